"""Screenshots of a 3D page of analysis.replay or analysis.region_volumes --view, taken in
headless Chromium at a chosen time of its animation.

    python -m benchmarks.browser replay.html --at 1.5 --out replay.png

Chromium is driven over its DevTools protocol on a pipe (``--remote-debugging-pipe``: no port,
no extra package), renders WebGL in software (SwiftShader), and answers questions about the
page's three.js scene: the animation's clock, where an object lies on screen. The browser test
of the 3D views runs on this, and so do the screenshots under ``results/``.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from typing import Any

from ddpg_her.config import Parser
from ur5kin.checks import integer, number

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
"""Executables tried, in order, when none is given (Debian's package is ``chromium``)."""

CHROMIUM_FLAGS = (
    "--headless",
    # Chromium refuses to run as root with its sandbox, and containers often lack the user
    # namespaces it needs; the pages opened are local files this project wrote.
    "--no-sandbox",
    # WebGL without a GPU: ANGLE over SwiftShader, which recent Chromium enables only on request
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--remote-debugging-pipe",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-extensions",
    "--mute-audio",
    "--hide-scrollbars",
)
"""Command-line flags of the headless browser."""

DEFAULT_SIZE = (960, 600)
"""Viewport (CSS pixels) of the screenshots: width, height."""

TIMEOUT_S = 30.0
"""Longest wait (s) for the browser to answer or for a page to be drawn."""

POLL_S = 0.1
"""Interval (s) between two looks at the page while waiting for it."""


class BrowserError(RuntimeError):
    """Chromium is missing, failed to start, or did not answer."""


def find_chromium() -> str | None:
    """Path of a Chromium executable on PATH (``$CHROMIUM`` first), or None."""
    for name in (os.environ.get("CHROMIUM", ""), *CHROMIUM_NAMES):
        path = shutil.which(name) if name else None
        if path:
            return path
    return None


class Browser:
    """One headless Chromium with one page, driven over the DevTools protocol on a pipe.

    Parameters
    ----------
    executable : str or None
        Chromium's path; None: :func:`find_chromium`.
    size : (int, int), CSS pixels
        Width and height of the viewport.
    timeout : float, s
        Longest wait for any answer.
    """

    def __init__(self, executable: str | None = None, size: Sequence[int] = DEFAULT_SIZE,
                 timeout: float = TIMEOUT_S) -> None:
        executable = executable or find_chromium()
        if executable is None:
            raise BrowserError("no Chromium found (tried $CHROMIUM, "
                               f"{', '.join(CHROMIUM_NAMES)}); on Debian: apt-get install "
                               "chromium")
        self.timeout = timeout
        self.size = (int(size[0]), int(size[1]))
        self._profile = tempfile.TemporaryDirectory(prefix="chromium-profile-")
        to_browser, self._out = os.pipe()   # we write commands, it reads fd 3
        self._in, from_browser = os.pipe()  # it writes answers on fd 4, we read
        self._buffer = b""
        self._events: list[dict[str, Any]] = []
        self._next_id = 0

        def wire_pipes() -> None:  # in the child: the pipe ends on the fds Chromium expects
            import fcntl

            # first above 4, so that neither dup2 overwrites the other end; dup2 also clears
            # the close-on-exec flag that os.pipe sets
            read_end = fcntl.fcntl(to_browser, fcntl.F_DUPFD, 10)
            write_end = fcntl.fcntl(from_browser, fcntl.F_DUPFD, 10)
            os.dup2(read_end, 3)
            os.dup2(write_end, 4)

        try:
            self.proc = subprocess.Popen(
                [executable, *CHROMIUM_FLAGS, f"--user-data-dir={self._profile.name}",
                 f"--window-size={self.size[0]},{self.size[1]}", "about:blank"],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                close_fds=False, preexec_fn=wire_pipes)
        except OSError as err:
            raise BrowserError(f"cannot start {executable}: {err}") from err
        finally:
            os.close(to_browser)
            os.close(from_browser)
        try:
            target = self._call("Target.createTarget", {"url": "about:blank"})["targetId"]
            self._session = self._call("Target.attachToTarget",
                                       {"targetId": target, "flatten": True})["sessionId"]
            self.call("Page.enable")
            self.call("Emulation.setDeviceMetricsOverride",
                      {"width": self.size[0], "height": self.size[1], "deviceScaleFactor": 1,
                       "mobile": False})
        except BaseException:
            self.close()
            raise

    # --- the protocol
    def _send(self, message: dict[str, Any]) -> int:
        self._next_id += 1
        message["id"] = self._next_id
        os.write(self._out, json.dumps(message).encode() + b"\0")
        return self._next_id

    def _receive(self, deadline: float) -> dict[str, Any]:
        import select

        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._in], [], [], left)[0]:
                raise BrowserError(f"Chromium did not answer within {self.timeout} s")
            chunk = os.read(self._in, 1 << 20)
            if not chunk:
                raise BrowserError(f"Chromium ended (exit status {self.proc.poll()})")
            self._buffer += chunk
        message, _, self._buffer = self._buffer.partition(b"\0")
        return json.loads(message)

    def _call(self, method: str, params: dict[str, Any] | None = None,
              session: str | None = None) -> dict[str, Any]:
        message: dict[str, Any] = {"method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        wanted = self._send(message)
        deadline = time.monotonic() + self.timeout
        while True:
            answer = self._receive(deadline)
            if answer.get("id") == wanted:
                if "error" in answer:
                    raise BrowserError(f"{method}: {answer['error'].get('message')}")
                return answer.get("result", {})
            if "method" in answer:
                self._events.append(answer)

    def call(self, method: str, params: dict[str, Any] | None = None) -> dict[str, Any]:
        """One DevTools command on the page; its result."""
        return self._call(method, params, self._session)

    # --- the page
    def open(self, page: str | os.PathLike) -> None:
        """Load a local HTML file (or URL) and wait for its load event."""
        url = page if str(page).startswith(("http:", "https:", "file:", "about:")) \
            else pathlib.Path(page).resolve().as_uri()
        self._events.clear()
        self.call("Page.navigate", {"url": url})
        deadline = time.monotonic() + self.timeout
        while not any(e.get("method") == "Page.loadEventFired" for e in self._events):
            self._events.append(self._receive(deadline))

    def evaluate(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page (promises awaited).

        Raises
        ------
        BrowserError
            When the expression throws; the message gives the page's error.
        """
        result = self.call("Runtime.evaluate", {"expression": expression,
                                                "returnByValue": True, "awaitPromise": True})
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            text = details.get("exception", {}).get("description") or details.get("text")
            raise BrowserError(f"the page threw: {text}")
        return result["result"].get("value")

    def wait_for(self, expression: str, what: str) -> Any:
        """Poll a JavaScript expression until it is truthy; its value. ``what`` names the wait
        in the error."""
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            value = self.evaluate(expression)
            if value:
                return value
            time.sleep(POLL_S)
        raise BrowserError(f"timed out after {self.timeout} s waiting for {what}")

    def screenshot(self) -> bytes:
        """The viewport as PNG bytes."""
        return base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"})["data"])

    def close(self) -> None:
        """End the browser and remove its profile."""
        if getattr(self, "proc", None) is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for fd in (getattr(self, "_out", None), getattr(self, "_in", None)):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._out = self._in = None
        self._profile.cleanup()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --- a MeshCat page
MESH_COUNT = "(() => { let n = 0; viewer.scene.traverse(o => { if (o.isMesh) n++; }); " \
             "return n; })()"
"""JavaScript: how many meshes the page's scene holds."""


class ViewerPage:
    """A MeshCat page open in a :class:`Browser`: waits until drawn; its animation's clock."""

    def __init__(self, browser: Browser, page: str | os.PathLike) -> None:
        self.browser = browser
        browser.open(page)
        browser.wait_for("typeof viewer !== 'undefined'", "the MeshCat viewer")
        # The page's drawing commands decode asynchronously after the load event: wait until
        # the number of meshes stops growing.
        counts = [-1, -2]
        deadline = time.monotonic() + browser.timeout
        while counts[-1] != counts[-2] or counts[-1] <= 0:
            if time.monotonic() > deadline:
                raise BrowserError(f"{page}: the scene was not drawn within {browser.timeout} s")
            time.sleep(5 * POLL_S)
            counts.append(browser.evaluate(MESH_COUNT))

    @property
    def duration(self) -> float:
        """Length (s) of the page's animation; 0 without one."""
        return float(self.browser.evaluate("viewer.animator.duration"))

    @property
    def time(self) -> float:
        """Where the animation is (s)."""
        return float(self.browser.evaluate("viewer.animator.time"))

    def seek(self, t: float) -> None:
        """Stop the animation at ``t`` (s) and draw that instant."""
        self.browser.evaluate(f"viewer.animator.pause(); viewer.animator.seek({float(t)}); "
                              "viewer.render(); true")

    def set_visible(self, path: Sequence[str], shown: bool) -> None:
        """Show or hide the scene node at ``path`` (e.g. ``["meshcat", "arm"]``) and redraw."""
        self.browser.evaluate(f"viewer.scene_tree.find({json.dumps(list(path))}).object"
                              f".visible = {'true' if shown else 'false'}; viewer.render(); true")

    def screen_box(self, path: Sequence[str]) -> tuple[int, int, int, int] | None:
        """Pixel box ``(x0, y0, x1, y1)`` of the node at ``path`` on screen now (its bounding
        box's corners projected), or None when it has no geometry."""
        script = """(() => {
            const T = MeshCat.THREE;
            const node = viewer.scene_tree.find(PATH).object;
            node.updateMatrixWorld(true);
            const box = new T.Box3().setFromObject(node);
            if (box.isEmpty()) return null;
            const w = viewer.renderer.domElement.clientWidth;
            const h = viewer.renderer.domElement.clientHeight;
            let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
            for (const x of [box.min.x, box.max.x]) for (const y of [box.min.y, box.max.y])
                for (const z of [box.min.z, box.max.z]) {
                    const p = new T.Vector3(x, y, z).project(viewer.camera);
                    const px = (p.x + 1) / 2 * w, py = (1 - p.y) / 2 * h;
                    x0 = Math.min(x0, px); x1 = Math.max(x1, px);
                    y0 = Math.min(y0, py); y1 = Math.max(y1, py);
                }
            return [x0, y0, x1, y1];
        })()""".replace("PATH", json.dumps(list(path)))
        box = self.browser.evaluate(script)
        if box is None:
            return None
        x0, y0, x1, y1 = box
        w, h = self.browser.size
        return (max(0, int(x0)), max(0, int(y0)), min(w, int(x1) + 1), min(h, int(y1) + 1))


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.browser``."""
    parser = Parser(
        prog="python -m benchmarks.browser", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("page", type=pathlib.Path, metavar="PAGE.html",
                        help="a page of analysis.replay or analysis.region_volumes --view")
    parser.add_argument("--at", type=number(0, note="s").read, default=None, metavar="T",
                        help="time of the animation to show (s, >= 0); None: the page as "
                        "loaded, its animation playing")
    parser.add_argument("--size", type=integer(64, note="pixels").read, nargs=2,
                        default=list(DEFAULT_SIZE),
                        metavar=("W", "H"), help="viewport width and height (CSS pixels, >= 64)")
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("screenshot.png"),
                        metavar="FILE.png", help="the PNG written")
    args = parser.parse_args(argv)
    if not args.page.is_file():
        parser.error(f"{args.page} is not a file")
    from analysis.outputs import check_writable, usage_errors, write_bytes, write_errors

    with usage_errors(parser):
        check_writable(args.out, "--out")
    try:
        with Browser(size=args.size) as browser:
            page = ViewerPage(browser, args.page)
            if args.at is not None:
                page.seek(min(args.at, page.duration))
            png = browser.screenshot()
    except BrowserError as err:
        print(f"benchmarks.browser: {err}", file=sys.stderr)
        return 1
    with write_errors(parser, force=True):  # a screenshot, rewritten
        write_bytes(args.out, png)
    print(f"-> {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
