"""The libLLVM that Dr.Jit loads: chosen once per process, before Dr.Jit starts.

Dr.Jit 1.5's LLVM backend aborts the process with Debian's libLLVM 14-16
(``LLVM ERROR: Cannot select ... fminimum``), so it is only used with LLVM 17
or newer. Importing Dr.Jit loads the library named by ``DRJIT_LIBLLVM_PATH``
(or one it finds itself), so :func:`prepare_libllvm` must run before the first
``import drjit``: every entry point runs it through :func:`core.launcher.start`,
and ``tests/conftest.py`` before it imports anything else.

A library that is named right can still be damaged (a truncated copy, a
garbage file called ``libLLVM-19.so``): loading it in this process ends in
SIGBUS or an ImportError deep inside Dr.Jit. So every candidate is first
*probed* in a short child process that loads it with Dr.Jit and runs one tiny
kernel; the verdict is cached under ``$XDG_CACHE_HOME/course-render/`` (or
``~/.cache/...``), keyed by the library's path, size and modification time,
so that a normal start pays for the probe once per library.

Standard library only: it runs before anything else is imported.
"""
from __future__ import annotations

import glob
import hashlib
import json
import os
import re
import signal
import subprocess
import sys
from dataclasses import dataclass
from importlib.util import find_spec
from pathlib import Path

#: Oldest libLLVM major version that Dr.Jit 1.5 works with
MIN_LLVM = 17
SEARCH = ("/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/llvm-*/lib/libLLVM*.so*",
          "/usr/lib64/libLLVM*.so*", "/usr/local/lib/libLLVM*.so*")
#: Seconds a probe may take (loading libLLVM and compiling one kernel takes ~0.5 s)
PROBE_TIMEOUT = 60
#: Loads the library given as argv[1] with Dr.Jit and runs one kernel
PROBE = ("import os, sys; os.environ['DRJIT_LIBLLVM_PATH'] = sys.argv[1]; import drjit as dr; "
         "from drjit.llvm import Float; x = dr.arange(Float, 4) * 2 + 1; dr.eval(x); "
         "assert x.numpy().tolist() == [1, 3, 5, 7]; print('ok')")


def llvm_major(path: str) -> int | None:
    """LLVM major version from a library name (``libLLVM-19.so``, ``libLLVM.so.19.1``)."""
    match = re.search(r"libLLVM(?:-(\d+)|\.so\.(\d+))", os.path.basename(path))
    if match is None:
        match = re.search(r"llvm-(\d+)", path)
        return int(match.group(1)) if match else None
    return int(match.group(1) or match.group(2))


def _cache_file() -> Path:
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(root) / "course-render" / "libllvm-probe.json"


#: Changes when the wording of cached verdicts does (older verdicts are then probed again)
VERDICT_FORMAT = 2


def first_sentence(line: str) -> str:
    """The first sentence of an error line, without its type and function
    prefixes (``RuntimeError: jit_init_thread_state(): the LLVM backend ...!
    Set ...`` gives ``the LLVM backend ...``), whole: never cut mid-word."""
    text = re.sub(r"^[\w.]+(Error|Exception): ", "", " ".join(line.split()))
    text = re.sub(r"^\w+\(\): ", "", text)
    match = re.match(r"(.+?)[.!?](\s|$)", text)
    return match.group(1) if match else text


def _key(path: str) -> str | None:
    """What a verdict depends on: the library's real path, size and mtime, and Dr.Jit's version."""
    try:
        real = os.path.realpath(path)
        stat = os.stat(real)
    except OSError:
        return None
    try:  # the installed Dr.Jit, by its file's stamp (cheaper than reading package metadata)
        origin = find_spec("drjit").origin
        drjit = f"{origin}@{os.stat(origin).st_mtime_ns}"
    except (ImportError, AttributeError, TypeError, OSError):  # no Dr.Jit: the probe then says no anyway
        drjit = "?"
    return hashlib.sha1(f"{VERDICT_FORMAT}|{real}|{stat.st_size}|{stat.st_mtime_ns}|{drjit}".encode()).hexdigest()


def _read_cache() -> dict:
    try:
        data = json.loads(_cache_file().read_text())
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


def _write_cache(cache: dict) -> None:
    path = _cache_file()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}")
        tmp.write_text(json.dumps(cache))
        os.replace(tmp, path)
    except OSError:
        pass  # no cache: the next start probes again


def probe_libllvm(path: str) -> str | None:
    """``None`` if Dr.Jit can load ``path`` and run a kernel with it, else why not (one line)."""
    key = _key(path)
    if key is None:
        return "cannot be read"
    cache = _read_cache()
    if key in cache:
        return cache[key] or None
    try:
        done = subprocess.run([sys.executable, "-c", PROBE, path], capture_output=True, text=True,
                              timeout=PROBE_TIMEOUT, env={**os.environ, "DRJIT_LIBLLVM_PATH": path})
        if -done.returncode in (signal.SIGINT, signal.SIGTERM):  # a Ctrl-C to the process group: says nothing
            return "its probe was interrupted"  # of the library, and is not cached
        if done.returncode == 0 and done.stdout.strip().endswith("ok"):
            why = ""
        elif done.returncode < 0:
            why = f"loading it ends in {_signal_name(-done.returncode)}"
        else:
            last = [line for line in done.stderr.splitlines() if line.strip()]
            why = "Dr.Jit cannot use it" + (f" ({first_sentence(last[-1])})" if last else "")
    except subprocess.TimeoutExpired:
        why = f"loading it takes more than {PROBE_TIMEOUT} s"
    except OSError as error:
        return f"cannot be probed ({error.strerror or error})"  # not cached: says nothing of the library
    cache[key] = why
    _write_cache(cache)
    return why or None


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"


def llvm_candidates() -> list[str]:
    """``DRJIT_LIBLLVM_PATH`` if set, else every libLLVM >= 17 found, newest first."""
    configured = os.environ.get("DRJIT_LIBLLVM_PATH")
    if configured:
        return [configured]
    found = {p: llvm_major(p) for pattern in SEARCH for p in glob.glob(pattern)}
    return [p for m, p in sorted(((m, p) for p, m in found.items() if m is not None and m >= MIN_LLVM),
                                 reverse=True)]


def choose_libllvm() -> tuple[str | None, list[str]]:
    """A libLLVM that Dr.Jit can use, and one line per candidate that was passed over."""
    notes = []
    configured = os.environ.get("DRJIT_LIBLLVM_PATH")
    for path in llvm_candidates():
        major = llvm_major(path)
        if not os.path.exists(path):
            notes.append(f"DRJIT_LIBLLVM_PATH={path} does not exist")
            continue
        if (major or 0) < MIN_LLVM:
            notes.append(f"DRJIT_LIBLLVM_PATH={path} is not LLVM >= {MIN_LLVM}")
            continue
        why = probe_libllvm(path)
        if why is None:
            return path, notes
        notes.append(f"{'DRJIT_LIBLLVM_PATH=' if configured else ''}{path} is damaged: {why}")
    if not notes:
        notes.append(f"no libLLVM >= {MIN_LLVM} found (apt-get install libllvm19)")
    return None, notes


def find_libllvm() -> str | None:
    """A usable libLLVM (>= 17, and one that loads): ``DRJIT_LIBLLVM_PATH`` if
    it is one, else the newest found that works."""
    return choose_libllvm()[0]


@dataclass(frozen=True)
class Choice:
    """What :func:`prepare_libllvm` chose: the library (``None``: no usable
    one, only scalar variants), one line per candidate passed over, and the
    command that chose it (the prefix of its notes)."""
    library: str | None
    notes: list[str]
    prog: str


_CHOICE: list[Choice] = []


def chosen() -> Choice | None:
    """The choice :func:`prepare_libllvm` made in this process, ``None`` before it ran."""
    return _CHOICE[0] if _CHOICE else None


def prepare_libllvm(prog: str | None = None) -> Choice:
    """Chooses the libLLVM (once per process: later calls return the first
    choice) and points ``DRJIT_LIBLLVM_PATH`` at it, or removes a damaged one
    from the environment so that it is never loaded. ``prog`` names the
    command in the notes (default: the script's name)."""
    if not _CHOICE:
        prog = prog or os.path.basename(sys.argv[0]) or "python"
        library, notes = choose_libllvm()
        if library is None:
            os.environ.pop("DRJIT_LIBLLVM_PATH", None)
        else:
            os.environ["DRJIT_LIBLLVM_PATH"] = library
        _CHOICE.append(Choice(library, notes, prog))
    return _CHOICE[0]
