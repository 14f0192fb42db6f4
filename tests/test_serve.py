"""``neuras-distill serve DIR`` (export/serve.py): a web export written by the real exporter served on 127.0.0.1
and fetched back byte for byte with its content types; which folders are served; the CLI's one-line errors
(a plain folder, a bad or taken --port) and its clean stop on Ctrl-C. No browser is opened."""

from __future__ import annotations

import re
import socket
import threading
import urllib.request
from pathlib import Path

import pytest
from test_bake import make_model_bundle

import neuras_distill.export.serve as serve_module
from neuras_distill.cli import main
from neuras_distill.errors import BadInputError
from neuras_distill.export.serve import RUN_MARKER, make_server, page_of, serve
from neuras_distill.export.threejs import MARKER as THREEJS_MARKER
from neuras_distill.export.web import export_web
from neuras_distill.pipeline.rundir import MARKER as RUNDIR_MARKER

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def web_folder(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("serve")
    return export_web(make_model_bundle(root), root / "web")


def _get(url: str) -> tuple[int, str, bytes]:
    with urllib.request.urlopen(url, timeout=10) as response:
        return response.status, response.headers["Content-Type"], response.read()


def test_serve_gives_the_web_export_byte_for_byte_and_stops_cleanly(web_folder, monkeypatch):
    servers, urls = [], []

    def capture(folder, port=0):
        server, url = make_server(folder, port)
        servers.append(server)
        return server, url

    monkeypatch.setattr(serve_module, "make_server", capture)
    ready = threading.Event()

    def bound(url: str) -> None:
        urls.append(url)
        ready.set()

    thread = threading.Thread(target=serve, args=(web_folder, 0), kwargs={"open_browser": False, "ready": bound})
    thread.start()
    try:
        assert ready.wait(10)
        url = urls[0]
        assert url.startswith("http://127.0.0.1:") and url.endswith("/index.html")
        status, kind, body = _get(url)
        assert status == 200 and kind.startswith("text/html") and body == (web_folder / "index.html").read_bytes()
        status, kind, body = _get(url.rsplit("/", 1)[0] + "/player.js")
        assert status == 200 and kind == "text/javascript" and body == (web_folder / "player.js").read_bytes()
    finally:
        servers[0].shutdown()
        thread.join(10)
    assert not thread.is_alive()
    with pytest.raises(OSError):                       # serve returned and closed its socket
        socket.create_connection(("127.0.0.1", servers[0].server_port), timeout=2).close()


def test_a_threejs_folder_is_served_with_module_and_wasm_types(tmp_path):
    (tmp_path / THREEJS_MARKER).write_text("{}")       # what export_threejs writes besides three/ and the glb
    (tmp_path / "index.html").write_text("<!doctype html>")
    (tmp_path / "three" / "build").mkdir(parents=True)
    (tmp_path / "three" / "build" / "three.module.mjs").write_text("export const a = 1;\n")
    (tmp_path / "a.wasm").write_bytes(b"\0asm\1\0\0\0")
    server, url = make_server(tmp_path, 0)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        base = url.rsplit("/", 1)[0]
        assert url == f"{base}/index.html"
        assert _get(f"{base}/three/build/three.module.mjs")[1] == "text/javascript"
        status, kind, body = _get(f"{base}/a.wasm")
        assert status == 200 and kind == "application/wasm" and body == b"\0asm\1\0\0\0"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(10)


def test_which_folders_are_served(tmp_path, web_folder):
    assert RUN_MARKER == RUNDIR_MARKER
    assert page_of(web_folder) == (web_folder.resolve(), "index.html")
    run = tmp_path / "run"
    run.mkdir()
    (run / RUN_MARKER).write_text("")
    with pytest.raises(BadInputError, match="no report.html"):
        page_of(run)
    (run / "report.html").write_text("<!doctype html>")
    assert page_of(run) == (run.resolve(), "report.html")
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "index.html").write_text("<!doctype html>")
    for folder in (plain, tmp_path / "missing", web_folder / "index.html"):
        with pytest.raises(BadInputError, match=re.escape("neuras-distill export --format web|threejs|3dtiles --out")):
            page_of(folder)


def test_the_page_opens_in_a_browser_but_never_a_console_one(monkeypatch):
    opened = []

    class Browser:
        def __init__(self, name: str):
            self.name = name

        def open(self, url: str) -> bool:
            opened.append((self.name, url))
            return True

    def none():
        raise serve_module.webbrowser.Error("could not locate runnable browser")

    for get in (lambda: Browser("lynx"), lambda: Browser("w3m"), none, lambda: Browser("firefox")):
        monkeypatch.setattr(serve_module.webbrowser, "get", get)
        serve_module.open_page("http://127.0.0.1:1/index.html").join(10)
    assert opened == [("firefox", "http://127.0.0.1:1/index.html")]


def _cli(capsys, argv) -> tuple[int, str, str]:
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("neuras-distill: error: ") and "Traceback" not in err, err
    return lines[0]


def test_a_plain_folder_with_an_index_html_exits_2_with_one_line(tmp_path, capsys):
    (tmp_path / "index.html").write_text("<!doctype html>")
    code, out, err = _cli(capsys, ["serve", str(tmp_path), "--no-open"])
    assert code == 2 and out == ""
    assert "is not a web, threejs or 3dtiles export or a run folder" in _one_error_line(err)


def test_a_taken_or_bad_port_exits_2_naming_port(web_folder, capsys):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code, out, err = _cli(capsys, ["serve", str(web_folder), "--port", str(port), "--no-open"])
        assert code == 2 and out == ""
        assert f"--port {port} is already in use" in _one_error_line(err)
    for bad in ("70000", "-1", "eighty"):
        code, out, err = _cli(capsys, ["serve", str(web_folder), "--port", bad, "--no-open"])
        assert code == 2 and out == "" and "--port" in _one_error_line(err)


def test_ctrl_c_stops_with_exit_0_and_one_line(web_folder, capsys, monkeypatch):
    def interrupted(self, poll_interval=0.5):
        raise KeyboardInterrupt

    monkeypatch.setattr(serve_module._Server, "serve_forever", interrupted)
    code, out, err = _cli(capsys, ["serve", str(web_folder), "--port", "0", "--no-open"])
    assert code == 0 and err == ""
    serving, stopped = out.splitlines()
    assert serving.startswith(f"serving {web_folder} at http://127.0.0.1:") and "/index.html" in serving
    assert stopped == f"stopped serving {web_folder}"
