"""Open a page in headless Chromium and report what a reader would see: whether every image
loaded, how many rows each table has, console errors and uncaught exceptions, and a
full-page screenshot.

Chromium is driven through the DevTools protocol over a pipe (``--remote-debugging-pipe``:
JSON messages, NUL-terminated, on file descriptors 3 and 4), so no websocket client, no
network port and no browser download are involved. :func:`find_chromium` finds the Debian
``chromium`` binary (``make chromium`` installs it; nothing here installs anything).
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

CANDIDATES = ("/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/lib/chromium/chromium")
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-dev-shm-usage", "--remote-debugging-pipe")

# Evaluated in the page after load: images (complete, naturalWidth) and table rows.
PROBE = """(async () => {
  const imgs = Array.from(document.images);
  await Promise.all(imgs.map(i => i.complete ? null :
      new Promise(r => { i.onload = r; i.onerror = r; })));
  return JSON.stringify({
    images: imgs.map(i => ({src: i.getAttribute('src'), width: i.naturalWidth})),
    tables: Array.from(document.querySelectorAll('table')).map(
        t => t.querySelectorAll('tbody tr').length),
    height: Math.ceil(document.documentElement.scrollHeight),
    title: document.title});
})()"""


def find_chromium() -> str | None:
    """Path of a Chromium binary (``$CHROMIUM`` first), or None."""
    env = os.environ.get("CHROMIUM")
    for c in ((env,) if env else ()) + CANDIDATES + (shutil.which("chromium") or "",):
        if c and os.path.isfile(c) and os.access(c, os.X_OK):
            return c
    return None


@dataclass
class PageCheck:
    images: list[dict]  # {src, width}
    tables: list[int]  # rows per table
    errors: list[str] = field(default_factory=list)  # console errors, exceptions, failed loads
    screenshot: Path | None = None
    title: str = ""

    @property
    def broken_images(self) -> list[str]:
        return [i["src"] for i in self.images if not i["width"]]


class BrowserError(RuntimeError):
    pass


class _Pipe:
    """DevTools protocol over Chromium's debugging pipe."""

    def __init__(self, proc: subprocess.Popen, to_browser: int, from_browser: int):
        self.proc, self.out, self.inp = proc, to_browser, from_browser
        self.buf = b""
        self.next_id = 0
        self.events: list[dict] = []

    def _read_message(self, deadline: float) -> dict:
        import select

        while b"\0" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BrowserError("timed out waiting for Chromium")
            ready, _, _ = select.select([self.inp], [], [], left)
            if ready:
                chunk = os.read(self.inp, 1 << 20)
                if not chunk:
                    raise BrowserError(f"Chromium closed the pipe (exit {self.proc.poll()})")
                self.buf += chunk
        msg, self.buf = self.buf.split(b"\0", 1)
        return json.loads(msg)

    def call(self, method: str, params: dict | None = None, session: str | None = None,
             timeout: float = 30) -> dict:
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self.out, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise BrowserError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def wait_event(self, method: str, timeout: float = 30) -> dict:
        for e in self.events:
            if e.get("method") == method:
                return e
        deadline = time.monotonic() + timeout
        while True:
            e = self._read_message(deadline)
            self.events.append(e)
            if e.get("method") == method:
                return e


def _errors(events: list[dict]) -> list[str]:
    out = []
    for e in events:
        m, p = e.get("method"), e.get("params", {})
        if m == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            out.append(f"exception: {d.get('exception', {}).get('description') or d.get('text')}")
        elif m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            out.append("console: " + " ".join(str(a.get("value", a.get("description", "")))
                                              for a in p.get("args", [])))
        elif m == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            en = p["entry"]
            out.append(f"log: {en.get('text')} {en.get('url', '')}".strip())
    return out


def inspect_page(page: str | Path, screenshot: str | Path | None = None,
                 chromium: str | None = None, width: int = 1280,
                 timeout: float = 60) -> PageCheck:
    """Load ``page`` (a local HTML file) in headless Chromium; see :class:`PageCheck`."""
    chromium = chromium or find_chromium()
    if not chromium:
        raise BrowserError("chromium not found")
    url = Path(page).resolve().as_uri()
    r1, w1 = os.pipe()  # browser reads commands from fd 3 (r1)
    r2, w2 = os.pipe()  # browser writes replies to fd 4 (w2)
    with tempfile.TemporaryDirectory(prefix="signsplat-chromium-") as profile:
        def child_fds():  # move the pipe ends to fds 3 and 4 without clobbering either
            a = fcntl.fcntl(r1, fcntl.F_DUPFD, 10)
            b = fcntl.fcntl(w2, fcntl.F_DUPFD, 10)
            os.dup2(a, 3)
            os.dup2(b, 4)

        proc = subprocess.Popen(
            [chromium, *FLAGS, f"--user-data-dir={profile}", f"--window-size={width},900",
             "about:blank"],
            pass_fds=(3, 4), preexec_fn=child_fds, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL)
        os.close(r1)
        os.close(w2)
        pipe = _Pipe(proc, w1, r2)
        try:
            target = pipe.call("Target.createTarget", {"url": "about:blank"}, timeout=timeout)
            sid = pipe.call("Target.attachToTarget", {"targetId": target["targetId"],
                                                      "flatten": True})["sessionId"]
            for domain in ("Page", "Runtime", "Log"):
                pipe.call(f"{domain}.enable", session=sid)
            pipe.call("Page.navigate", {"url": url}, session=sid)
            pipe.wait_event("Page.loadEventFired", timeout)
            res = pipe.call("Runtime.evaluate", {"expression": PROBE, "awaitPromise": True,
                                                 "returnByValue": True}, session=sid,
                            timeout=timeout)
            probe = json.loads(res["result"]["value"])
            shot = None
            if screenshot is not None:
                pipe.call("Emulation.setDeviceMetricsOverride",
                          {"width": width, "height": min(int(probe["height"]), 16000),
                           "deviceScaleFactor": 1, "mobile": False}, session=sid)
                data = pipe.call("Page.captureScreenshot", {"format": "png"}, session=sid,
                                 timeout=timeout)["data"]
                shot = Path(screenshot)
                shot.parent.mkdir(parents=True, exist_ok=True)
                shot.write_bytes(base64.b64decode(data))
            errors = _errors(pipe.events)
            try:
                pipe.call("Browser.close", timeout=10)
            except BrowserError:
                pass
        finally:
            os.close(w1)
            os.close(r2)
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    return PageCheck(probe["images"], probe["tables"], errors, shot, probe["title"])
