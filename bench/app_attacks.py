"""Replay the attacks of issue 11 against a running ``skinloc app``; each must be refused.

A real app (``python -m skinloc app`` on a free loopback port, a temporary data folder) gets a
session with recorded touches and an uploaded mesh, then:

* cross-site requests as a page on ``http://127.0.0.1:9999`` sends them with
  ``fetch(..., {mode: "no-cors"})`` (its Origin, a text/plain body, no token), without Origin,
  with a guessed token, and with the token but a non-JSON body;
* WebSocket handshakes from other origins, without Origin, without the token;
* ``POST /api/connect`` to pyserial URLs (``spy://`` aimed at a file, ``socket://`` at a
  listening port, ...), the same ports on the command line, a Host header of another name;
* mesh uploads: 200 MB streamed in chunks (peak memory of the server measured), a declared
  200 MB, a body that is not a mesh over the good mesh of that name, a 422 that would echo the
  body, and the mesh listing after a restart;
* every endpoint with bad input (missing, empty, truncated, foreign files; absurd numbers;
  wrong types): a 4xx with a one-line message, never a 500 or a traceback (the server's own log
  is checked too).

Each row says what was expected, what came back and whether the file the attack aimed at is
untouched (sha256 before and after). The exit status is 1 if any attack got through.

    PYTHONPATH=src python bench/app_attacks.py            # docs/reliability.md
    PYTHONPATH=src python bench/app_attacks.py --quick    # smaller upload (the test suite)
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import re
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

EVIL_ORIGIN = "http://127.0.0.1:9999"
MB = 1024 * 1024
LIMIT = 64 * MB


@dataclass
class Row:
    """One attack (or one bad input) and what became of it."""

    group: str
    attack: str
    expected: str
    got: str
    untouched: bool | None  # None: the attack aims at no file
    ok: bool


# ------------------------------------------------------------------------------------ the app
def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free right now on ``host``."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def sha(path: Path) -> str | None:
    """The sha256 of a file, or None when there is none."""
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def tree(folder: Path) -> dict[str, str | None]:
    """The sha256 of every file under ``folder``, by relative path."""
    return {str(p.relative_to(folder)): sha(p) for p in sorted(folder.rglob("*")) if p.is_file()}


class App:
    """``skinloc app`` in a child process on a free port; ``page`` acts as its own page."""

    def __init__(self, data: Path, host: str = "127.0.0.1") -> None:
        self.data = data
        self.host = host
        self.port = free_port(host)
        shown = f"[{host}]" if ":" in host else host
        self.url = f"http://{shown}:{self.port}"
        self.origin = self.url
        self.log = data.parent / f"app-{self.port}.log"
        self.proc: subprocess.Popen | None = None
        self.token = ""
        self.page: httpx.Client | None = None

    def __enter__(self) -> App:
        cmd = [sys.executable, "-m", "skinloc", "app", "--no-browser", "--data", str(self.data)]
        cmd += ["--host", self.host, "--port", str(self.port)]
        import skinloc

        # The child runs the same skinloc as this process (a worktree's src, not an install).
        src = str(Path(skinloc.__file__).resolve().parents[1])
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([src, os.environ.get("PYTHONPATH", "")])}
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
        deadline = time.monotonic() + 60
        while True:
            try:
                page = httpx.get(self.url + "/", timeout=2)
                break
            except httpx.HTTPError:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"the app did not start: {self.log.read_text()}") from None
                time.sleep(0.2)
        found = re.search(r'<meta name="skinloc-token" content="([^"]+)"', page.text)
        if not found:
            raise RuntimeError("the page carries no skinloc-token")
        self.token = found.group(1)
        headers = {"X-Skinloc-Token": self.token, "X-Skinloc-Client": "tab-page"}
        self.page = httpx.Client(base_url=self.url, headers=headers, timeout=30)
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.page is not None:
            self.page.close()
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def peak_rss_mb(self) -> float:
        """The server's peak resident memory so far, MB (Linux; nan elsewhere)."""
        try:
            text = Path(f"/proc/{self.proc.pid}/status").read_text()
        except OSError:
            return float("nan")
        return int(re.search(r"VmHWM:\s+(\d+)", text).group(1)) / 1024

    def state(self) -> dict[str, Any]:
        return self.page.get("/api/state").json()

    def wait(self, check: Callable[[dict], bool], what: str, timeout_s: float = 120) -> dict:
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.state()
            if check(state):
                return state
            if time.monotonic() > deadline:
                raise RuntimeError(f"timed out waiting for {what}: {state}")
            time.sleep(0.1)


def prepare(app: App, n_points: int = 5) -> dict[str, Path]:
    """A session with ``n_points`` recorded touches and an uploaded ``cone.stl``, as the page."""
    from skinloc.geometry.mesh import cone_skin

    page = app.page
    page.post("/api/connect", json={"source": "sim", "rate_hz": 200.0}).raise_for_status()
    body = {"name": "attacked", "n_points": n_points, "samples": 10, "baseline_frames": 20}
    sid = page.post("/api/sessions", json=body).raise_for_status().json()["id"]
    page.post("/api/finger", json={"on": True}).raise_for_status()
    page.post("/api/calibrate/start").raise_for_status()
    app.wait(lambda s: s["message"] == "calibration complete", "the calibration")
    page.post("/api/finger", json={"on": False}).raise_for_status()
    stl = cone_skin().export(file_type="stl")
    page.post("/api/meshes?filename=cone.stl", content=stl).raise_for_status()
    folder = app.data / sid
    return {
        "session": folder,
        "calibration": folder / "calibration.h5",
        "history": folder / "history.h5",
        "mesh": app.data / "meshes" / "cone.stl",
    }


def refused(status: int, want: tuple[int, ...] = (403,)) -> bool:
    return status in want


def describe(r: httpx.Response) -> str:
    try:
        detail = r.json().get("detail", "")
    except (ValueError, AttributeError):
        detail = r.text
    detail = str(detail).replace("|", "/")
    return f"{r.status_code} {detail[:90]}{'...' if len(detail) > 90 else ''}".strip()


# ------------------------------------------------------------------------- cross-site requests
#: What the page on another origin posted; the undo five times, as in the issue.
CROSS_SITE = [
    ("/api/lease", None),
    ("/api/capture/stop", None),
    *[("/api/capture/undo", None)] * 5,
    ("/api/meshes?filename=cone.stl", "not a mesh"),
    ("/api/session/close", None),
    ("/api/disconnect", None),
    ("/api/connect", '{"source": "sim"}'),
    ("/api/sessions", '{"n_points": 3}'),
    ("/api/recordings/import?path=x.h5", None),
    ("/api/train", None),
]


def attacks_cross_site(app: App, files: dict[str, Path]) -> list[Row]:
    """Requests no page but the app's own may make: refused with 403, nothing changed."""
    rows = []
    before = tree(app.data)
    state0 = app.state()
    evil = httpx.Client(base_url=app.url, timeout=30)
    # What Chromium sends for fetch(url, {method: "POST", mode: "no-cors", body: "..."}).
    no_cors = {
        "Origin": EVIL_ORIGIN,
        "Content-Type": "text/plain;charset=UTF-8",
        "Sec-Fetch-Mode": "no-cors",
        "Sec-Fetch-Site": "same-site",
        "X-Skinloc-Client": "tab-evil",
    }
    for path, body in CROSS_SITE:
        target = files["mesh"] if "meshes" in path else files["calibration"]
        h = sha(target)
        r = evil.post(path, content=body or b"", headers=no_cors)
        rows.append(
            Row(
                "cross-site",
                f"no-cors POST {path} from {EVIL_ORIGIN}",
                "403",
                describe(r),
                sha(target) == h,
                refused(r.status_code),
            )
        )
    variants = [
        ("without Origin, without token", {"Content-Type": "text/plain"}, (403,)),
        ("guessed token", {"X-Skinloc-Token": "x" * 43, "Content-Type": "text/plain"}, (403,)),
        (
            "right token but from another Origin",
            {"X-Skinloc-Token": app.token, "Origin": EVIL_ORIGIN},
            (403,),
        ),
        (
            "right token but a text/plain body",
            {"X-Skinloc-Token": app.token, "Content-Type": "text/plain"},
            (415,),
        ),
        (
            "right token but a form body",
            {
                "X-Skinloc-Token": app.token,
                "Content-Type": "application/x-www-form-urlencoded",
            },
            (415,),
        ),
    ]
    for what, headers, want in variants:
        h = sha(files["calibration"]), sha(files["history"])
        statuses = []
        for _ in range(5):
            r = evil.post("/api/capture/undo", content=b"{}", headers=headers)
            statuses.append(r)
        rows.append(
            Row(
                "cross-site",
                f"5 x POST /api/capture/undo, {what}",
                " / ".join(map(str, want)),
                describe(statuses[-1]),
                (sha(files["calibration"]), sha(files["history"])) == h,
                all(refused(s.status_code, want) for s in statuses),
            )
        )
    evil.close()
    state1 = app.state()
    same = (
        tree(app.data) == before
        and state1["lease"] == state0["lease"]
        and (state1["session"] or {}).get("id") == (state0["session"] or {}).get("id")
        and bool(state1["device"]) == bool(state0["device"])
    )
    rows.append(
        Row(
            "cross-site",
            "after all of the above: data folder, open session, skin, control",
            "unchanged",
            "unchanged" if same else "CHANGED",
            tree(app.data) == before,
            same,
        )
    )
    return rows


def attack_host(app: App) -> list[Row]:
    """DNS rebinding: the app's address under another name."""
    rows = []
    for method in ("GET", "POST"):
        r = httpx.request(method, app.url + "/api/state", headers={"Host": "evil.example"})
        rows.append(
            Row(
                "host",
                f"{method} with Host: evil.example (DNS rebinding)",
                "400",
                f"{r.status_code} {r.text[:40]}",
                None,
                r.status_code == 400,
            )
        )
    return rows


# ---------------------------------------------------------------------------------- WebSocket
def ws_try(url: str, origin: str | None) -> str:
    """``accepted`` or the refusal of a WebSocket handshake to ``url`` from ``origin``."""
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    kw: dict[str, Any] = {"open_timeout": 10}
    if origin is not None:
        kw["origin"] = origin
    try:
        with connect(url, **kw) as ws:
            first = json.loads(ws.recv(timeout=10))
            return f"accepted ({first.get('type')})"
    except InvalidStatus as exc:
        return f"refused {exc.response.status_code}"
    except (OSError, TimeoutError) as exc:
        return f"refused ({type(exc).__name__})"


def attacks_websocket(app: App) -> list[Row]:
    """Handshakes from elsewhere are refused; the page's own (control) is accepted."""
    ws = app.url.replace("http://", "ws://") + "/ws?client=tab-x"
    with_token = f"{ws}&token={app.token}"
    port = app.port
    cases = [
        (with_token, "http://localhost:1234", False),
        (with_token, EVIL_ORIGIN, False),
        (with_token, "https://localhost", False),
        (with_token, f"https://127.0.0.1:{port}", False),
        (with_token, None, False),
        (with_token, "null", False),
        (ws, app.origin, False),
        (f"{ws}&token=guess", app.origin, False),
        (with_token, app.origin, True),
    ]
    if app.host == "127.0.0.1":
        cases.append((with_token, f"http://localhost:{port}", True))
    rows = []
    for url, origin, allowed in cases:
        got = ws_try(url, origin)
        token = (
            "no token"
            if "token=" not in url
            else ("token" if allowed or "guess" not in url else "guessed token")
        )
        label = f"Origin {origin or '(none)'}, {token}" + (" (control)" if allowed else "")
        rows.append(
            Row(
                "websocket",
                label,
                "accepted" if allowed else "refused",
                got,
                None,
                got.startswith("accepted") == allowed,
            )
        )
    return rows


# -------------------------------------------------------------------------- sources and ports
@contextlib.contextmanager
def listener() -> Iterator[socket.socket]:
    """A TCP listener on a free loopback port (what ``socket://`` would connect to)."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    srv.settimeout(1.0)
    try:
        yield srv
    finally:
        srv.close()


def connected(srv: socket.socket) -> bool:
    try:
        conn, _ = srv.accept()
    except TimeoutError:
        return False
    conn.close()
    return True


def attacks_sources(app: App, tmp: Path) -> list[Row]:
    """``/api/connect`` and the command line take ``sim`` or a serial device, nothing else."""
    from typer.testing import CliRunner

    from skinloc.cli.main import app as cli

    victim = tmp / "precious.txt"
    victim.write_text("a file that spy:// would truncate\n")
    rows = []
    device_before = (app.state()["device"] or {}).get("name")
    with listener() as srv:
        sock_url = f"socket://127.0.0.1:{srv.getsockname()[1]}"
        cases = [
            (f"spy://loop://?file={victim}", victim),
            (sock_url, None),
            ("rfc2217://127.0.0.1:1", None),
            ("loop://", None),
            ("hwgrep://.*", None),
            (str(victim), victim),
            (str(tmp), None),
        ]
        for source, target in cases:
            h = sha(victim)
            r = app.page.post("/api/connect", json={"source": source})
            opened = connected(srv) if source == sock_url else False
            rows.append(
                Row(
                    "sources",
                    f"page POST /api/connect {source.replace(str(tmp), 'TMP')}",
                    "400, says what is allowed",
                    describe(r) + (" [TCP connection made]" if opened else ""),
                    sha(victim) == h if target else None,
                    r.status_code == 400 and "'sim'" in r.text and not opened,
                )
            )
        for args in (
            ["monitor", "--port", f"spy://loop://?file={victim}"],
            ["record", "--port", sock_url, "--out", str(tmp / "x.h5")],
            ["collect", "--port", "loop://", "--out", str(tmp / "y.h5")],
        ):
            h = sha(victim)
            res = CliRunner().invoke(cli, args)
            opened = connected(srv)
            line = (res.output.strip().splitlines() or [""])[-1]
            shown = " ".join(args[:3]).replace(str(tmp), "TMP")
            rows.append(
                Row(
                    "sources",
                    f"skinloc {shown}",
                    "exit 1, names --allow-url",
                    f"exit {res.exit_code}: {line[:60]}...",
                    sha(victim) == h,
                    res.exit_code == 1 and "--allow-url" in res.output and not opened,
                )
            )
    device_after = (app.state()["device"] or {}).get("name")
    rows.append(
        Row(
            "sources",
            "the skin connected before the refused requests",
            "still connected",
            f"{device_after}",
            None,
            device_after == device_before and device_after is not None,
        )
    )
    return rows


# -------------------------------------------------------------------------------- mesh upload
def chunks(total: int, size: int = MB) -> Iterator[bytes]:
    """``total`` bytes of an STL-looking header and zeros, ``size`` at a time (never all)."""
    block = b"\0" * size
    sent = 0
    while sent < total:
        n = min(size, total - sent)
        yield block[:n]
        sent += n


def raw_post(app: App, path: str, headers: dict[str, str], body: bytes = b"") -> tuple[int, str]:
    """A POST over a plain socket (a declared length need not be sent); status and body."""
    host, port = app.host, app.port
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family) as s:
        s.settimeout(30)
        s.connect((host, port))
        head = f"POST {path} HTTP/1.1\r\nHost: {app.url.split('//')[1]}\r\n"
        head += "".join(f"{k}: {v}\r\n" for k, v in headers.items()) + "\r\n"
        s.sendall(head.encode() + body)
        data = b""
        while b"\r\n\r\n" not in data or len(data.split(b"\r\n\r\n", 1)[1]) == 0:
            part = s.recv(65536)
            if not part:
                break
            data += part
    status = int(data.split(b" ", 2)[1]) if data.startswith(b"HTTP/") else 0
    text = data.split(b"\r\n\r\n", 1)[-1].decode(errors="replace")
    with contextlib.suppress(ValueError, AttributeError):
        text = json.loads(text)["detail"]
    return status, text


def attacks_upload(app: App, files: dict[str, Path], oversize: int) -> list[Row]:
    """Uploads that must fail without memory blow-up, echo or loss of the good mesh."""
    rows = []
    mesh = files["mesh"]
    folder = mesh.parent

    # 1. Far over the limit, streamed in 1 MB chunks with no declared length.
    h, peak0 = sha(mesh), app.peak_rss_mb()
    try:
        r = app.page.post("/api/meshes?filename=cone.stl", content=chunks(oversize))
        got = describe(r)
        status = r.status_code
    except httpx.HTTPError as exc:  # the server may close the connection mid-stream
        got, status = f"connection closed ({type(exc).__name__})", 413
    grew = app.peak_rss_mb() - peak0
    left = [p.name for p in folder.iterdir() if p.name.startswith(".upload")]
    rows.append(
        Row(
            "upload",
            f"{oversize / MB:.0f} MB streamed (chunked) over cone.stl",
            "413, peak memory +<32 MB, no partial file",
            f"{got}; server peak RSS {peak0:.0f} -> {peak0 + grew:.0f} MB; "
            f"partial file: {left or 'none'}",
            sha(mesh) == h,
            status == 413 and not grew > 32 and not left,
        )
    )

    # 2. A declared 200 MB: refused before a byte of it is read.
    h = sha(mesh)
    status, text = raw_post(
        app,
        "/api/meshes?filename=cone.stl",
        {
            "X-Skinloc-Token": app.token,
            "X-Skinloc-Client": "tab-page",
            "Content-Length": str(200 * MB),
        },
    )
    rows.append(
        Row(
            "upload",
            "Content-Length: 200 MB, no body sent",
            "413 at once",
            f"{status} {text[:60]}",
            sha(mesh) == h,
            status == 413,
        )
    )

    # 3. Not a mesh, under the name of the good one.
    for what, body in (
        ("text", b"not a mesh"),
        ("the first 300 bytes of the STL", mesh.read_bytes()[:300]),
        ("a PNG", b"\x89PNG\r\n\x1a\n" + bytes(200)),
    ):
        h = sha(mesh)
        r = app.page.post("/api/meshes?filename=cone.stl", content=body)
        rows.append(
            Row(
                "upload",
                f"{what} uploaded as cone.stl over the good one",
                "400, cone.stl kept",
                describe(r),
                sha(mesh) == h,
                r.status_code == 400 and sha(mesh) == h,
            )
        )

    # 4. A 422 must not echo the request.
    marker = "ECHO-" + "x" * 100_000
    for path, body in (
        ("/api/sessions", {"name": marker}),
        ("/api/connect", {"source": "sim", "tx": marker}),
        ("/api/capture/retake", {"index": marker}),
    ):
        r = app.page.post(path, json=body)
        echoed = "ECHO-" in r.text
        rows.append(
            Row(
                "upload",
                f"422 on {path} with a 100 kB field",
                "422, body not echoed",
                f"{describe(r)} ({len(r.content)} bytes{', ECHOED' if echoed else ''})",
                None,
                r.status_code == 422 and not echoed and len(r.content) < 1000,
            )
        )
    return rows


def attack_listing_after_restart(data: Path, files: dict[str, Path], before: str) -> list[Row]:
    """The uploaded mesh is still listed (and still the good one) by a new app process."""
    with App(data) as app:
        listed = [m["name"] for m in app.page.get("/api/meshes").json()]
    return [
        Row(
            "upload",
            "GET /api/meshes after a restart (what the page shows on reload)",
            "cone.stl listed",
            ", ".join(listed) or "nothing",
            sha(files["mesh"]) == before,
            "cone.stl" in listed,
        )
    ]


# ------------------------------------------------------------------- the same from a browser
EVIL_PAGE = """<!doctype html><title>another site</title><script>
async function attack(app, token) {
  const out = {};
  const posts = [["/api/lease"], ["/api/capture/stop"], ["/api/capture/undo"],
    ["/api/capture/undo"], ["/api/capture/undo"], ["/api/capture/undo"], ["/api/capture/undo"],
    ["/api/meshes?filename=cone.stl", "not a mesh"], ["/api/session/close"],
    ["/api/disconnect"], ["/api/connect", JSON.stringify({source: "spy://loop://"})]];
  out.no_cors = [];
  for (const [path, body] of posts) {
    try {
      await fetch(app + path, {method: "POST", mode: "no-cors", body: body ?? ""});
      out.no_cors.push("sent");
    } catch (e) { out.no_cors.push("blocked: " + e); }
  }
  try {  // a CORS request with the header: its preflight gets no permission
    const r = await fetch(app + "/api/capture/undo", {method: "POST",
      headers: {"X-Skinloc-Token": "guess", "Content-Type": "application/json"}, body: "{}"});
    out.cors = "answered " + r.status;
  } catch (e) { out.cors = "blocked: " + e.message; }
  try {  // reading the page (and its token) from here
    const r = await fetch(app + "/");
    out.read_page = "read " + (await r.text()).length + " chars";
  } catch (e) { out.read_page = "blocked: " + e.message; }
  out.ws = await new Promise((resolve) => {
    const ws = new WebSocket(app.replace("http", "ws") + "/ws?client=evil&token=" + token);
    ws.onmessage = () => resolve("STREAM RECEIVED");
    ws.onerror = () => resolve("refused");
    setTimeout(() => resolve("no answer"), 8000);
  });
  return out;
}
</script>"""


def attacks_in_a_browser(app: App, files: dict[str, Path]) -> list[Row]:
    """The issue's attack for real: headless Chromium on a page of another origin.

    Skipped (no rows) where Playwright or Chromium is missing. The page cannot see answers
    (no-cors), so the rows judge by the app's files and state afterwards. The WebSocket is
    even given the real token: the Origin alone must stop it.
    """
    import http.server
    import shutil
    import threading

    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        return []
    chromium = next(
        (p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p),
        None,
    )
    if chromium is None:
        return []

    class Evil(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 - the http.server name
            body = EVIL_PAGE.encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: Any) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Evil)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    evil_url = f"http://127.0.0.1:{server.server_address[1]}/"
    before, state0 = tree(app.data), app.state()
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
            page = browser.new_page()
            page.goto(evil_url)
            out = page.evaluate("([app, token]) => attack(app, token)", [app.url, app.token])
            browser.close()
    finally:
        server.shutdown()
        server.server_close()
    state1 = app.state()
    same_state = (
        state1["lease"] == state0["lease"]
        and (state1["session"] or {}).get("id") == (state0["session"] or {}).get("id")
        and bool(state1["device"]) == bool(state0["device"])
    )
    untouched = tree(app.data) == before
    where = f"Chromium on {evil_url}"
    return [
        Row(
            "browser",
            f"{where}: 11 no-cors POSTs (lease, stop, 5 x undo, mesh, close, disconnect, "
            "connect spy://)",
            "no effect",
            "no effect" if untouched and same_state else "STATE CHANGED",
            untouched,
            untouched and same_state,
        ),
        Row(
            "browser",
            f"{where}: POST with X-Skinloc-Token (CORS preflight)",
            "blocked",
            out["cors"][:70],
            None,
            out["cors"].startswith("blocked"),
        ),
        Row(
            "browser",
            f"{where}: read the app's page (and its token)",
            "blocked",
            out["read_page"][:70],
            None,
            out["read_page"].startswith("blocked"),
        ),
        Row(
            "browser",
            f"{where}: WebSocket, even with the real token",
            "refused",
            out["ws"],
            None,
            out["ws"] == "refused",
        ),
    ]


# ---------------------------------------------------------------------------------- bad input
def bad_inputs(app: App, files: dict[str, Path], tmp: Path) -> list[Row]:
    """Every endpoint with bad input, as the page itself: 4xx and one line, never 5xx."""
    stl = files["mesh"].read_bytes()
    sid = files["session"].name
    junk = tmp / "junk.h5"
    junk.write_bytes(b"not hdf5 at all")
    inside_junk = app.data / "junk.h5"
    inside_junk.write_bytes(b"not hdf5 at all")
    big = 10**30
    nan = float("nan")
    cases: list[tuple[str, str, str, Any]] = [
        # (method, path, what, body): body is json (dict/list/None), bytes (raw) or str (text)
        ("GET", f"/api/sessions/{sid}/targets.png", "sheet in png", None),
        ("GET", "/api/sessions/nope/targets.svg", "sheet of no session", None),
        ("GET", "/api/sessions/..%2F..%2Fetc/targets.svg", "sheet of ../../etc", None),
        ("GET", f"/api/sessions/{'a' * 5000}/targets.pdf", "sheet of a 5000-char id", None),
        ("POST", "/api/connect", "no body", None),
        ("POST", "/api/connect", "empty source", {"source": ""}),
        ("POST", "/api/connect", "truncated JSON", b'{"source": "si'),
        ("POST", "/api/connect", "JSON array", [1, 2]),
        ("POST", "/api/connect", "JSON null", b"null"),
        ("POST", "/api/connect", "tx 0", {"tx": 0}),
        ("POST", "/api/connect", "tx 10^30", {"tx": big}),
        ("POST", "/api/connect", "tx 'eight'", {"tx": "eight"}),
        ("POST", "/api/connect", "baud -1", {"baud": -1}),
        ("POST", "/api/connect", "rate_hz NaN", b'{"rate_hz": NaN}'),
        ("POST", "/api/connect", "rate_hz 1e308", {"rate_hz": 1e308}),
        ("POST", "/api/connect", "format 'morse'", {"format": "morse"}),
        ("POST", "/api/connect", "seed 10^30", {"source": "sim", "seed": big}),
        ("POST", "/api/connect", "seed -1", {"source": "sim", "seed": -1}),
        ("POST", "/api/sessions", "n_points 0", {"n_points": 0}),
        ("POST", "/api/sessions", "n_points 10^9", {"n_points": 10**9}),
        ("POST", "/api/sessions", "n_points 'many'", {"n_points": "many"}),
        ("POST", "/api/sessions", "n_points 2.5", {"n_points": 2.5}),
        ("POST", "/api/sessions", "mode 'spiral'", {"mode": "spiral"}),
        ("POST", "/api/sessions", "mesh_file ../../etc/passwd", {"mesh_file": "../../etc/passwd"}),
        ("POST", "/api/sessions", "mesh_file missing", {"mesh_file": "nope.stl"}),
        ("POST", "/api/sessions", "list mode, no targets", {"mode": "list"}),
        ("POST", "/api/sessions", "list mode, garbage", {"mode": "list", "targets_csv": "a,b"}),
        ("POST", "/api/sessions", "list mode, NaN", {"mode": "list", "targets_csv": "nan,0,0"}),
        ("POST", "/api/sessions", "seed 10^30", {"seed": big, "n_points": 3}),
        ("POST", "/api/sessions", "seed -1", {"seed": -1, "n_points": 3}),
        ("POST", "/api/sessions", "name of 5000 chars", {"name": "n" * 5000}),
        ("POST", "/api/sessions/nope/open", "open no session", None),
        ("POST", "/api/sessions/..%2F..%2Ftmp/open", "open ../../tmp", None),
        ("POST", "/api/recordings/import", "import, no path", None),
        ("POST", "/api/recordings/import?path=", "import, empty path", None),
        ("POST", "/api/recordings/import?path=/etc/passwd", "import /etc/passwd", None),
        ("POST", f"/api/recordings/import?path={junk}", "import a file outside the data", None),
        ("POST", f"/api/recordings/import?path={inside_junk}", "import a foreign .h5", None),
        ("POST", "/api/meshes", "upload, no filename", stl),
        ("POST", "/api/meshes?filename=", "upload, empty filename", stl),
        ("POST", "/api/meshes?filename=x.txt", "upload x.txt", stl),
        ("POST", "/api/meshes?filename=.hidden.stl", "upload .hidden.stl", stl),
        ("POST", "/api/meshes?filename=../../evil.stl", "upload ../../evil.stl", b"solid x"),
        ("POST", "/api/meshes?filename=e.stl", "upload, empty body", b""),
        ("POST", "/api/meshes?filename=t.stl", "upload, truncated STL", stl[: len(stl) // 2 + 3]),
        (
            "POST",
            "/api/meshes?filename=t.obj",
            "upload OBJ with NaN",
            b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        ),
        ("POST", "/api/meshes?filename=t.obj", "upload OBJ, faces only", b"f 1 2 3\n"),
        ("POST", "/api/meshes?filename=t.ply", "upload garbage .ply", b"ply\nformat junk\n"),
        ("POST", "/api/sim/touch", "touch [1, 2]", {"point": [1, 2]}),
        ("POST", "/api/sim/touch", "touch ['a', 'b', 'c']", {"point": ["a", "b", "c"]}),
        ("POST", "/api/sim/touch", "touch NaN", b'{"point": [NaN, 0, 0]}'),
        ("POST", "/api/sim/touch", "touch 1e308", {"point": [1e308, 0, 0]}),
        ("POST", "/api/sim/touch", "touch 4 coordinates", {"point": [0, 0, 0, 0]}),
        ("POST", "/api/sim/touch", "touch 'here'", {"point": "here"}),
        ("POST", "/api/validate/start", "n_points 0", {"n_points": 0}),
        ("POST", "/api/validate/start", "n_points 'x'", {"n_points": "x"}),
        ("POST", "/api/validate/start", "validate with no model", {}),
        ("POST", "/api/capture/retake", "retake -1", {"index": -1}),
        ("POST", "/api/capture/retake", "retake 10^12", {"index": 10**12}),
        ("POST", "/api/capture/retake", "retake 'x'", {"index": "x"}),
        ("POST", "/api/capture/retake", "retake in 'foo'", {"index": 0, "recording": "foo"}),
        ("POST", "/api/capture/retake", "retake, no body", None),
        ("POST", "/api/capture/dance", "unknown capture action", None),
        ("POST", "/api/finger", "finger 'maybe'", {"on": "maybe"}),
        ("POST", "/api/finger", "finger, no body", None),
        ("POST", "/api/live/start", "live with no model", None),
        ("POST", "/api/state", "POST to a GET endpoint", None),
        ("DELETE", "/api/sessions", "DELETE", None),
    ]
    del nan
    rows = []
    for method, path, what, body in cases:
        kw: dict[str, Any] = {}
        if isinstance(body, bytes):
            kw = {"content": body}
            if "meshes" not in path:
                kw["headers"] = {"Content-Type": "application/json"}
        elif body is not None:
            kw = {"json": body}
        r = app.page.request(method, path, **kw)
        try:
            detail = r.json().get("detail")
        except (ValueError, AttributeError):
            detail = None
        good = 400 <= r.status_code < 500 and isinstance(detail, str) and "\n" not in detail
        rows.append(
            Row(
                "bad input",
                f"{method} {path[:60]}: {what}",
                "4xx + message",
                describe(r),
                None,
                good,
            )
        )
    # No session, no skin: the actions that need them say so.
    app.page.post("/api/session/close").raise_for_status()
    app.page.post("/api/disconnect").raise_for_status()
    for path in (
        "/api/calibrate/start",
        "/api/train",
        "/api/rezero",
        "/api/capture/now",
        "/api/live/start",
    ):
        r = app.page.post(path)
        good = 400 <= r.status_code < 500 and isinstance(r.json().get("detail"), str)
        rows.append(
            Row(
                "bad input",
                f"POST {path} with no session and no skin",
                "4xx + message",
                describe(r),
                None,
                good,
            )
        )
    inside_junk.unlink()
    return rows


# --------------------------------------------------------------------------------------- main
def run_all(
    workdir: Path, oversize: int = 200 * MB, ipv6: bool = True, browser: bool = True
) -> list[Row]:
    """Every attack and bad input against fresh apps in ``workdir``; the rows."""
    data = workdir / "sessions"
    data.mkdir(parents=True, exist_ok=True)
    rows: list[Row] = []
    with App(data) as app:
        files = prepare(app)
        rows += attacks_cross_site(app, files)
        if browser:
            rows += attacks_in_a_browser(app, files)
        rows += attack_host(app)
        rows += attacks_websocket(app)
        rows += attacks_sources(app, workdir)
        rows += attacks_upload(app, files, oversize)
        mesh_sha = sha(files["mesh"])
        rows += bad_inputs(app, files, workdir)
        log = app.log
    rows += attack_listing_after_restart(data, files, mesh_sha)
    if ipv6 and socket.has_ipv6:
        try:
            free_port("::1")
        except OSError:
            ipv6 = False
    if ipv6 and socket.has_ipv6:
        with App(workdir / "sessions6", host="::1") as app6:
            for row in attacks_websocket(app6):
                row.group = "websocket [::1]"
                rows.append(row)
    text = log.read_text(errors="replace")
    crashed = "Traceback" in text or "Exception in ASGI" in text
    rows.append(
        Row(
            "bad input",
            "the server's own log after all of the above",
            "no traceback",
            "traceback!" if crashed else "no traceback",
            None,
            not crashed,
        )
    )
    for row in rows:  # the temporary folder's name changes with every run
        row.attack = row.attack.replace(str(workdir), "TMP")
        row.got = row.got.replace(str(workdir), "TMP")
    return rows


def table(rows: list[Row], groups: tuple[str, ...]) -> str:
    """A markdown table of the rows in ``groups``."""
    out = ["| group | attack | expected | got | target untouched | refused |", "|---" * 6 + "|"]
    for r in rows:
        if r.group.split(" ")[0] not in groups:
            continue
        untouched = "-" if r.untouched is None else ("yes" if r.untouched else "**NO**")
        out.append(
            f"| {r.group} | {r.attack} | {r.expected} | {r.got} | {untouched} | "
            f"{'yes' if r.ok else '**NO**'} |"
        )
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a 70 MB upload instead of 200 MB")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="skinloc-attacks-") as tmp:
        rows = run_all(Path(tmp), oversize=(LIMIT + 6 * MB) if args.quick else 200 * MB)
    print("## attacks\n")
    print(table(rows, ("cross-site", "browser", "host", "websocket", "sources", "upload")))
    print("\n## bad input\n")
    print(table(rows, ("bad",)))
    failed = [r for r in rows if not r.ok or r.untouched is False]
    print(f"\n{len(rows)} checks, {len(failed)} failed")
    if args.json:
        args.json.write_text(json.dumps([r.__dict__ for r in rows], indent=1))
    for r in failed:
        print(f"FAILED: {r.group}: {r.attack}: got {r.got}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
