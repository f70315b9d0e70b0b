"""Shared helpers for tests that run the real `cdpr` command and services as OS processes."""

from __future__ import annotations

import contextlib
import functools
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import pytest

from cdpr.tools.launch import free_port as free_port  # the tests' free port: the launcher's

CDPR = [sys.executable, "-m", "cdpr"]
ROOT = Path(__file__).resolve().parent.parent
DOCKER = ROOT / "docker"  # the compose files that test_compose, test_acl and test_docker run
COMPOSE = DOCKER / "compose.yaml"
SECURE = DOCKER / "compose.secure.yaml"
REALTIME = DOCKER / "compose.realtime.yaml"


# The modules that cost the most, first: pytest-xdist hands each worker whole modules (make test: --dist
# loadscope) in collection order, so that the longest do not start last and leave one worker alone at the end.
# A scheduling hint only: any order passes.
COSTLY_FIRST = ("test_fuzz.py", "test_ros2.py", "test_acl.py", "test_faults.py", "test_realtime.py",
                "test_experiments.py", "test_load.py", "test_winch_loop.py", "test_bench.py", "test_cable_models.py",
                "test_remote.py", "test_camera.py", "test_study.py", "test_gym.py", "test_pulley.py")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(COSTLY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: within a module, its own order


def source_copy(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A copy of the repository's ``shared`` and ``services`` (to change as a contributor would), and the environment
    that runs ``python -m cdpr`` from it."""
    tree = tmp_path / "tree"
    for folder in ("shared", "services"):
        shutil.copytree(ROOT / folder, tree / folder, ignore=shutil.ignore_patterns("__pycache__"))
    path = [str(tree / "shared"), *(str(p) for p in sorted((tree / "services").glob("*")))]
    return tree, {**os.environ, "PYTHONPATH": os.pathsep.join(path), "PYTHONDONTWRITEBYTECODE": "1"}


def changed_sources(tree: Path) -> list[str]:
    """The Python files of a :func:`source_copy` that are new or differ from the repository's."""
    import filecmp

    files = sorted(str(f.relative_to(tree)) for folder in ("shared", "services") for f in (tree / folder).rglob("*.py"))
    return [f for f in files if not (ROOT / f).exists() or not filecmp.cmp(ROOT / f, tree / f, shallow=False)]


def last_json_line(stdout: str) -> dict:
    lines = [ln for ln in stdout.strip().splitlines() if ln.strip()]
    assert lines, "no output on stdout"
    return json.loads(lines[-1])


def cdpr(*args: str, timeout: float = 120.0, check: bool = False) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([*CDPR, *args], capture_output=True, text=True, timeout=timeout, check=False)
    if check and proc.returncode != 0:
        raise AssertionError(f"cdpr {' '.join(args)} exited {proc.returncode}\n{proc.stderr[-3000:]}")
    return proc


def cdpr_here(*args: str) -> subprocess.CompletedProcess[str]:
    """`cdpr ARGS` in this process (cdpr.tools.cli.main: its output, one-line errors and exit codes): for the checks
    of what a command prints and its exit code, where a module also runs the command as a real process."""
    from cdpr.tools.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(list(args))
            code = 0
        except SystemExit as exc:
            code = 0 if exc.code is None else exc.code if isinstance(exc.code, int) else 1
    return subprocess.CompletedProcess(["cdpr", *args], code, out.getvalue(), err.getvalue())


ONE_PROCESS = """
import contextlib, io, json, sys, traceback
from cdpr.tools.cli import main
results = []
for argv in json.loads(sys.argv[1]):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(argv)
            code = 0
        except SystemExit as exc:
            code = 0 if exc.code is None else exc.code if isinstance(exc.code, int) else 1
        except Exception:
            traceback.print_exc()
            code = 1
    results.append([code, out.getvalue(), err.getvalue()])
with open(sys.argv[2], "w") as f:
    json.dump(results, f)
"""


def cdpr_in_one_process(argvs: list[list[str]], result: Path, timeout: float) -> list[subprocess.CompletedProcess[str]]:
    """`cdpr ARGV` for each ARGV one after the other in one Python process, each one as its own `cdpr` command
    (cdpr.tools.cli.main), the interpreter's start-up shared (importing cdpr, DART and Zenoh: about a CPU-second
    a command); their exit codes, stdouts and stderrs."""
    proc = subprocess.run([*CDPR[:1], "-c", ONE_PROCESS, json.dumps(argvs), str(result)], capture_output=True,
                          text=True, timeout=timeout, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return [subprocess.CompletedProcess(["cdpr", *argv], code, out, err)
            for argv, (code, out, err) in zip(argvs, json.loads(result.read_text()), strict=True)]


def processes_mentioning(text: str) -> list[int]:
    """PIDs of live processes whose command line contains ``text`` (zombies excluded)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            status = (entry / "status").read_text()
        except OSError:
            continue
        if text in cmdline and "State:\tZ" not in status:
            found.append(int(entry.name))
    return found


def wait_no_processes(text: str, timeout: float = 5.0) -> list[int]:
    deadline = time.monotonic() + timeout
    while (left := processes_mentioning(text)) and time.monotonic() < deadline:
        time.sleep(0.05)
    return left


def sigterm_the_recorder(run: subprocess.Popen[str], session_id: str, path: Path, min_bytes: int,
                         timeout: float) -> tuple[str, str]:
    """Once the recorder of ``run`` (a ``cdpr run`` of ``session_id``) is up and ``path`` holds more than
    ``min_bytes``, send it SIGTERM; return the run's stdout and stderr (the run is killed if it outlives
    the test)."""
    try:
        deadline = time.monotonic() + timeout
        recorder: list[int] = []
        while time.monotonic() < deadline:
            recorder = sorted(set(processes_mentioning(session_id)) & set(processes_mentioning(" recorder ")))
            if recorder and path.exists() and path.stat().st_size > min_bytes:
                break
            assert run.poll() is None, run.stderr.read() if run.stderr else ""
            time.sleep(0.05)
        assert len(recorder) == 1
        os.kill(recorder[0], signal.SIGTERM)
        out, err = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
    return out, err


@pytest.fixture
def session_id() -> Iterator[str]:
    """A unique session id; afterwards no process may still carry it."""
    sid = f"t{uuid.uuid4().hex[:12]}"
    yield sid
    left = wait_no_processes(sid, timeout=10.0)
    for pid in left:  # do not leak processes into later tests, but fail this one
        with contextlib.suppress(OSError):
            os.kill(pid, 9)
    assert not left, f"processes of session {sid} were left behind: {left}"


ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts"

RT_PRIORITY = 20  # SCHED_FIFO priority of the realtime tests' processes


@functools.cache
def realtime_scheduling() -> bool:
    """Whether tests may run processes under SCHED_FIFO (root, or CAP_SYS_NICE with an rtprio limit: CI)."""
    from cdpr.tools.bench import rt_priority_allowed

    return shutil.which("chrt") is not None and rt_priority_allowed(RT_PRIORITY)


def realtime(argv: Sequence[str]) -> list[str]:
    """``argv`` under SCHED_FIFO at :data:`RT_PRIORITY` where that is permitted (``chrt``; its children inherit
    it), else as it is. A test whose outcome is a wall-clock figure (steps on time, command ages, the watchdog)
    runs its session's processes so — as a realtime deployment does (docs/realtime.md: ``--rt-priority``) — so
    that the suite's other workers and a CPU burner at normal priority do not decide it."""
    return ["chrt", "--fifo", str(RT_PRIORITY), *argv] if realtime_scheduling() else list(argv)


def run_once(tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], dict]) -> tuple[dict, Path]:
    """``make(directory)`` run once per test session, however many pytest-xdist workers ask: the first one runs it
    (under a file lock, in a directory all workers share) and keeps its JSON result, the others wait and read
    it. Returns (result, directory). A ``make`` that raises fails every test that asks (each tries again)."""
    from filelock import FileLock

    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # pytest-of-<user>/pytest-N/: the workers' basetemps are popen-gwK/ below it
    directory = base / f"once-{name}"
    with FileLock(str(directory) + ".lock"):
        result = directory / "result.json"
        if result.exists():
            return json.loads(result.read_text()), directory
        directory.mkdir(exist_ok=True)
        value = make(directory)
        result.write_text(json.dumps(value))
        return value, directory


@pytest.fixture(scope="session")
def half_second_run(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The summary of `cdpr run caroca_15kg --duration 0.5`, run once per test session, for the tests that compare a
    run of their own with it."""
    def run(directory: Path) -> dict:
        proc = cdpr("run", "caroca_15kg", "--duration", "0.5", "--session", f"half{uuid.uuid4().hex[:8]}", "--quiet",
                    check=True)
        return last_json_line(proc.stdout)

    return run_once(tmp_path_factory, "caroca_15kg-0.5s", run)[0]


@pytest.fixture(scope="session")
def ibvs_in_process(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, str]:
    """`cdpr run caroca_15kg_ibvs --in-process` (the whole IBVS session: 12 000 steps), run once per test session:
    its summary and its log (stderr), for the tests that compare a session of their own with it."""
    def run(directory: Path) -> dict:
        proc = cdpr("run", "caroca_15kg_ibvs", "--in-process", "--quiet", "--session", f"ibvs{uuid.uuid4().hex[:8]}",
                    timeout=600, check=True)
        return {"summary": last_json_line(proc.stdout), "stderr": proc.stderr}

    value = run_once(tmp_path_factory, "ibvs-in-process", run)[0]
    return value["summary"], value["stderr"]


@pytest.fixture(scope="session")
def demo_recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    """The demo (`make demo`'s run: the whole 15 kg CAROCA scenario), recorded once per test session: its
    summary and its .rrd (``.with_suffix(".mcap")``: the same session as MCAP)."""
    def run(directory: Path) -> dict:
        rrd = directory / "caroca_15kg.rrd"
        proc = cdpr("run", "caroca_15kg", "--rrd", str(rrd), "--mcap", str(rrd.with_suffix(".mcap")),
                    "--session", f"demo{uuid.uuid4().hex[:8]}", "--quiet", timeout=600, check=True)
        return last_json_line(proc.stdout)

    summary, directory = run_once(tmp_path_factory, "demo", run)
    return summary, directory / "caroca_15kg.rrd"


@pytest.fixture(scope="session")
def sdk_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The environment of a zenoh-ros2-sdk process (a ROS 2 peer written by someone else): its message cache
    offline (no git clone from GitHub), and a git configuration of its own (the SDK marks its cache as a git
    safe.directory in the global one)."""
    from cdpr.tools.bench.ros2_messages import make_cache

    root = tmp_path_factory.mktemp("ros2")
    env = {**os.environ, "ZENOH_ROS2_SDK_CACHE": str(make_cache(root / "cache")),
           "GIT_CONFIG_GLOBAL": str(root / "gitconfig"), "ROS_DOMAIN_ID": "0"}
    (root / "gitconfig").write_text("")
    return env
