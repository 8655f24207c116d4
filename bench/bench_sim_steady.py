"""Do ``omnican drive --sim``'s simulated drives keep their heartbeats beside a busy
desktop? (issue 36, item 1)

Runs ``omnican drive --sim --foxglove ... --record bus.log`` at the config's 100 Hz for
``--duration`` seconds (circling: ``--speed 0.2 --omega 0.3``), once per scenario:

- ``browser``: beside headless Chromium rendering Foxglove's web app (the web build of
  open-source Foxglove Studio, ``@foxglove/studio-base`` from npm, installed once into
  ~/.cache/omnican like the interop tests' packages, served on loopback by this script)
  with the shipped layout (foxglove/omnican-layout.json), connected to the live view;
- ``client``: beside a Foxglove client that subscribes to every channel and reads one
  message every ``--read-every`` seconds (tests/support/stalled_foxglove_client.py);
- ``quiet``: nothing beside (the reference).

``--hogs N`` adds N CPU-bound processes at normal priority to each scenario (a busier
desktop). From the recording (frames stamped as they reached the bus): each simulated
drive's heartbeats and their longest gap, every EMCY 8130h (a drive that lost the host's
heartbeat), the host's own heartbeat's longest gap, from the first host heartbeat to the
last; from the run: its exit status and the base's stop, if any ("heartbeat lost" trips).

``--checkout PATH`` runs another copy of omnican (PYTHONPATH=PATH, the same Python and
dependencies), so "before" (main) and "after" run alike: ``python
bench/bench_sim_steady.py --checkout /path/to/main --duration 600``. Prints one JSON
object per scenario.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
APP = HERE / "foxglove_app"
LAYOUT = ROOT / "foxglove" / "omnican-layout.json"
HOST_HEARTBEAT = 0x77F  # the default config's host node 127
DRIVES = (1, 2, 3)
HOG = "while True: pass"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--window-size=1600,1000",
                  "--remote-debugging-port=0"]

# The page: React 17 (the app's peer dependency) and the app's UMD build, which takes
# React from window.react / window["react-dom"] and puts its exports on window; then the
# app itself as Foxglove's web app starts it (App with the Foxglove WebSocket source),
# its layout storage holding only the shipped layout, opened by the deep link.
INDEX = """<!doctype html><html><head><meta charset="utf-8"><title>Foxglove (omnican bench)</title>
<style>html, body, #root { height: 100%; margin: 0; }</style></head>
<body><div id="root"></div>
<script src="/react/umd/react.production.min.js"></script>
<script src="/react-dom/umd/react-dom.production.min.js"></script>
<script>window.react = window.React; window["react-dom"] = window.ReactDOM;</script>
<script src="/studio/index.js"></script>
<script src="/boot.js"></script></body></html>
"""
BOOT = """
(async () => {
  const S = window;
  const data = await (await fetch("/layout.json")).json();
  const stamp = new Date().toISOString();
  const layout = { id: "omnican", name: "omnican", permission: "CREATOR_WRITE",
    baseline: { data, savedAt: stamp }, working: undefined, syncInfo: undefined };
  const storage = { list: async () => [layout],
    get: async (ns, id) => (id === layout.id ? layout : undefined),
    put: async (ns, l) => l, delete: async () => {}, importLayouts: async () => {},
    migrateUnnamespacedLayouts: async () => {} };
  const values = new Map([["launchPreference", "web"]]);
  const appConfiguration = { get: (k) => values.get(k),
    set: async (k, v) => { values.set(k, v); },
    addChangeListener: () => {}, removeChangeListener: () => {} };
  if (S.initI18n) { await S.initI18n(); }
  ReactDOM.render(React.createElement(S.App, { deepLinks: [location.href], appConfiguration,
    dataSources: [new S.FoxgloveWebSocketDataSourceFactory()], layoutStorage: storage,
    extensionLoaders: [], enableLaunchPreferenceScreen: false, enableGlobalCss: true }),
    document.getElementById("root"));
  setInterval(() => fetch("/alive?text=" +
    encodeURIComponent(document.body.innerText.slice(0, 400))), 5000);
})().catch((e) => fetch("/alive?error=" + encodeURIComponent(String((e && e.stack) || e))));
"""


def emit(**fields: Any) -> None:
    print(json.dumps(fields), flush=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# ------------------------------------------------------------ the recording


def analyse(log: Path) -> dict[str, Any]:
    """Heartbeats and EMCY 8130h from a candump-format recording, from the first host
    heartbeat (the loop running) to the last."""
    frames = []
    pattern = re.compile(r"\((\d+\.\d+)\) \S+ ([0-9A-F]+)#([0-9A-F]*)")
    with log.open() as fh:
        for line in fh:
            m = pattern.match(line)
            if m:
                frames.append((float(m[1]), int(m[2], 16), m[3]))
    host = [t for t, i, _ in frames if i == HOST_HEARTBEAT]
    if not host:
        return {"error": "no host heartbeat recorded"}
    start, end = host[0], host[-1]

    def longest_gap(times: list[float]) -> float | None:
        gaps = [b - a for a, b in itertools.pairwise(times)]
        return round(max(gaps) * 1000, 1) if gaps else None

    out: dict[str, Any] = {"host_heartbeat_longest_gap_ms": longest_gap(host)}
    gaps, counts, emcy = {}, {}, {}
    for node in DRIVES:
        beats = [t for t, i, _ in frames if i == 0x700 + node and start <= t <= end]
        counts[node] = len(beats)
        gaps[node] = longest_gap(beats)
        emcy[node] = sum(1 for t, i, d in frames if i == 0x80 + node and len(d) >= 4
                         and d[2:4] + d[0:2] == "8130")
    out.update(drive_heartbeats=counts, drive_heartbeat_longest_gap_ms=gaps, emcy_8130=emcy,
               recorded_s=round(end - start, 1))
    return out


# ------------------------------------------------------------ the web app


def app_modules() -> Path:
    sys.path.insert(0, str(ROOT))
    from tests.interop.foxglove_node.harness import node_modules

    path, note = node_modules(APP)
    if path is None:
        raise SystemExit(f"bench_sim_steady: the Foxglove web app: {note}")
    return path


class AppServer:
    """Foxglove's web app and the page that starts it, on 127.0.0.1; the page reports
    what it shows every few seconds (``/alive``)."""

    def __init__(self, modules: Path) -> None:
        roots = {"studio": modules / "@foxglove" / "studio-base" / "assets",
                 "react": modules / "react", "react-dom": modules / "react-dom"}
        pages = {"/": (INDEX.encode(), "text/html"), "/boot.js": (BOOT.encode(), "text/javascript"),
                 "/layout.json": (LAYOUT.read_bytes(), "application/json")}
        self.alive = 0
        self.text = ""
        self.error: str | None = None
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                url = urllib.parse.urlsplit(self.path)
                if url.path == "/alive":
                    query = urllib.parse.parse_qs(url.query)
                    outer.alive += 1
                    outer.text = query.get("text", [outer.text])[0]
                    outer.error = query.get("error", [outer.error])[0]
                    body, kind = b"", "text/plain"
                elif url.path in pages:
                    body, kind = pages[url.path]
                else:
                    top, _, rest = url.path.lstrip("/").partition("/")
                    base = roots.get(top)
                    file = (base / rest).resolve() if base is not None else None
                    if file is None or base is None or not file.is_file() or \
                            base.resolve() not in file.parents:
                        self.send_error(404)
                        return
                    body = file.read_bytes()
                    kind = {".js": "text/javascript", ".wasm": "application/wasm",
                            ".png": "image/png", ".ttf": "font/ttf"}.get(file.suffix,
                                                                         "application/octet-stream")
                self.send_response(200)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.origin = f"http://127.0.0.1:{self.server.server_address[1]}"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def url(self, ws_url: str) -> str:
        query = urllib.parse.urlencode({"ds": "foxglove-websocket", "ds.url": ws_url,
                                        "layoutId": "omnican"})
        return f"{self.origin}/?{query}"

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def screenshot(devtools: str, path: Path) -> str | None:
    """The page's picture through Chromium's DevTools protocol; None, or why not."""
    import base64
    import urllib.request

    from websockets.sync.client import connect

    try:
        port = urllib.parse.urlsplit(devtools).port
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=10) as r:
            pages = [p for p in json.load(r) if p.get("type") == "page"]
        with connect(pages[0]["webSocketDebuggerUrl"], max_size=None, open_timeout=10) as ws:
            ws.send(json.dumps({"id": 1, "method": "Page.captureScreenshot"}))
            while True:
                answer = json.loads(ws.recv(timeout=30))
                if answer.get("id") == 1:
                    break
        path.write_bytes(base64.b64decode(answer["result"]["data"]))
        return None
    except Exception as exc:  # a bench's picture is a bonus
        return str(exc)


# ------------------------------------------------------------ one run


@contextlib.contextmanager
def beside(argvs: list[list[str]], cwd: Path = ROOT) -> Iterator[list[subprocess.Popen[bytes]]]:
    procs = [subprocess.Popen(a, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, cwd=cwd) for a in argvs]
    try:
        yield procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.communicate()


def run(scenario: str, args: argparse.Namespace, env: dict[str, str], work: Path,
        modules: Path | None) -> dict[str, Any]:
    port = free_port()
    log = work / f"{scenario}.log"
    server = AppServer(modules) if scenario == "browser" and modules is not None else None
    cmd = [args.python, "-m", "omnican", "-v", "drive", "--sim", "--foxglove",
           f"127.0.0.1:{port}", "--speed", "0.2", "--omega", "0.3", "--duration",
           str(args.duration), "--record", str(log)]
    if server is not None:
        cmd += ["--foxglove-origin", server.origin]
    ws_url = f"ws://127.0.0.1:{port}"
    others: list[list[str]] = [[args.python_beside, "-c", HOG]] * args.hogs
    result: dict[str, Any] = {"bench": "sim_steady", "scenario": scenario,
                              "checkout": str(args.checkout), "duration_s": args.duration,
                              "hogs": args.hogs}
    drive = subprocess.Popen(cmd, env=env, cwd=work, stdin=subprocess.DEVNULL,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err_lines: list[str] = []
    reader = threading.Thread(target=lambda: err_lines.extend(drive.stderr or []), daemon=True)
    reader.start()
    profile = Path(tempfile.mkdtemp(prefix="chromium-", dir=work))
    browser: subprocess.Popen[bytes] | None = None
    try:
        deadline = time.monotonic() + 60
        while not any("open a connection" in line for line in err_lines):
            if drive.poll() is not None or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        if scenario == "client":
            others.append([args.python_beside, "-m", "tests.support.stalled_foxglove_client",
                           ws_url, str(args.read_every)])
        with beside(others):
            if server is not None:
                chromium = shutil.which("chromium") or shutil.which("chromium-browser")
                assert chromium is not None
                browser = subprocess.Popen(
                    ["nice", "-n", str(args.browser_nice), chromium, *CHROMIUM_FLAGS,
                     f"--user-data-dir={profile}", server.url(ws_url)],
                    stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                    start_new_session=True)  # its renderers end with it (killpg)
            if browser is not None and args.shots is not None and browser.stderr is not None:
                devtools = ""
                for raw in iter(browser.stderr.readline, b""):
                    text = raw.decode(errors="replace")
                    if "DevTools listening on" in text:
                        devtools = text.split("on ", 1)[1].strip()
                        break
                # The picture while the run goes on: near its end, the app still live.
                with contextlib.suppress(subprocess.TimeoutExpired):
                    drive.wait(timeout=max(args.duration - 5.0, args.duration * 0.8))
                shot = Path(args.shots) / f"{scenario}-{int(time.time())}.png"
                shot.parent.mkdir(parents=True, exist_ok=True)
                why = screenshot(devtools, shot) if devtools else "no DevTools address"
                result["screenshot"] = str(shot) if why is None else f"none: {why}"
            drive.wait(timeout=args.duration + 120)
    finally:
        if drive.poll() is None:
            drive.kill()
            drive.wait()
        if browser is not None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(browser.pid, signal.SIGKILL)
            browser.wait()
        reader.join(5)
        shutil.rmtree(profile, ignore_errors=True)
        if server is not None:
            server.close()
    out = drive.stdout.read() if drive.stdout is not None else ""
    stops = [line.strip() for line in err_lines if "base stopped" in line or "error:" in line]
    result.update(exit=drive.returncode, stops=stops[:5],
                  heartbeat_trips=sum("heartbeat lost" in line for line in stops),
                  viewers=sum("Foxglove viewer" in line and "connected" in line
                              for line in err_lines),
                  pose=out.strip().splitlines()[-1] if out.strip() else None)
    if server is not None:
        result["browser"] = {"alive_reports": server.alive, "error": server.error,
                             "page_text": server.text[:200]}
    result.update(analyse(log) if log.is_file() else {"error": "no recording"})
    if not args.keep:
        log.unlink(missing_ok=True)
    return result


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=float, default=600.0, help="seconds per scenario")
    p.add_argument("--scenarios", default="browser,client",
                   help="comma-separated: browser, client, quiet (default browser,client)")
    p.add_argument("--checkout", type=Path, default=ROOT,
                   help="the omnican to run (a clone or worktree; default this one)")
    p.add_argument("--python", default=sys.executable, help="the Python that runs omnican")
    p.add_argument("--hogs", type=int, default=0, help="CPU-bound processes beside (default 0)")
    p.add_argument("--read-every", type=float, default=0.5,
                   help="the client scenario's client reads a message this often (s)")
    p.add_argument("--browser-nice", type=int, default=0, help="Chromium's nice value")
    p.add_argument("--shots", help="save a screenshot of the app at the end into this folder")
    p.add_argument("--keep", action="store_true", help="keep the recordings (in a temp dir)")
    args = p.parse_args()
    args.python_beside = sys.executable
    scenarios = [s.strip() for s in args.scenarios.split(",") if s.strip()]
    unknown = set(scenarios) - {"browser", "client", "quiet"}
    if unknown:
        p.error(f"unknown scenarios: {', '.join(sorted(unknown))}")
    checkout = args.checkout.resolve()
    if not (checkout / "omnican" / "__init__.py").is_file():
        p.error(f"--checkout {checkout}: no omnican package there")
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    found = subprocess.run([args.python, "-c", "import omnican; print(omnican.__file__)"],
                           env=env, capture_output=True, text=True, cwd=tempfile.gettempdir(),
                           check=False)
    if not found.stdout.strip().startswith(str(checkout)):
        p.error(f"--checkout {checkout}: {args.python} imports omnican from "
                f"{found.stdout.strip() or found.stderr.strip()[-200:]}")
    modules = None
    if "browser" in scenarios:
        if shutil.which("chromium") is None and shutil.which("chromium-browser") is None:
            p.error("the browser scenario needs Chromium (Debian: apt-get install chromium)")
        modules = app_modules()
    work = Path(tempfile.mkdtemp(prefix="bench-sim-steady-"))
    try:
        for scenario in scenarios:
            emit(**run(scenario, args, env, work, modules))
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
        else:
            print(f"recordings kept in {work}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
