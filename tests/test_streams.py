"""The state stream is declared once (cdpr.protocol.streams.STATE_COLUMNS): the ``sim/state`` message, the
telemetry blocks, the recorder's rows and Rerun series, the MCAP channels and ``cdpr convert`` follow it.

The cost of a new state field is shown on a copy of the tree: one column, one attribute of ``State``, and its
producer in the sim — three files — and a whole session then carries it to the .rrd, the .mcap and back."""

from __future__ import annotations

import filecmp
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import msgspec
import numpy as np
import pytest

from cdpr.protocol import State, Telemetry
from cdpr.protocol.streams import STATE_COLUMNS

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("shared", "services")


def test_the_state_message_has_the_columns_in_their_order() -> None:
    fields = msgspec.structs.fields(State)
    assert [f.name for f in fields] == ["step", "t", *(c.name for c in STATE_COLUMNS)]
    for f, c in zip(fields[2:], STATE_COLUMNS, strict=True):
        assert (f.default is msgspec.NODEFAULT) == (c.default is None), c.name  # optional on the wire = a default
        if c.default is not None:
            assert f.default == c.default


def test_a_state_round_trips_through_the_columns() -> None:
    s = State(7, 0.007, (0.1, 0.2, 1.5, 0.0, 0.0, 0.0, 1.0), (0.5,) * 6, (1.25, 2.5), (100.0, 200.0), 3)
    assert State.decode(s.encode(), 2) == s
    block = Telemetry((s, msgspec.structs.replace(s, step=8, t=0.008, clamped=4)))
    assert Telemetry.decode(block.encode(), 2).states == block.states


# The test-only field: the platform's translational kinetic energy, J.
COLUMN = '''    Column("energy", 1, "J", "translational kinetic energy of the platform", default=0.0,
           series=(Series("actual/energy"),), fields=(ChannelField(PLATFORM_STATE, "energy"),)),
)
STATE = {c.name: c for c in STATE_COLUMNS}'''
LAST = "    watchdog: int = 0  # 1 if the watchdog policy acted over the step before (instead of a command)"
ATTRIBUTE = LAST + '''
    energy: float = 0.0  # J'''
PRODUCER = '''                     tuple(lengths.tolist()), tuple(self._tensions.tolist()), clamped,
                     energy=0.5 * self.robot.mass * sum(x * x for x in twist[3:]))'''


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text(encoding="utf-8")
    assert text.count(old) == 1, f"{path}: the place to edit is not there once"
    path.write_text(text.replace(old, new), encoding="utf-8")


def _changed(tree: Path) -> list[str]:
    """The source files of the repository that differ in ``tree`` (a copy of its SOURCES)."""
    files = subprocess.run(["git", "ls-files", *SOURCES], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    return [f for f in files if f.endswith(".py") and not filecmp.cmp(ROOT / f, tree / f, shallow=False)]


@pytest.mark.slow
def test_a_new_state_field_is_a_column_an_attribute_and_its_producer(tmp_path: Path) -> None:
    tree = tmp_path / "tree"
    for folder in SOURCES:
        shutil.copytree(ROOT / folder, tree / folder, ignore=shutil.ignore_patterns("__pycache__"))
    _edit(tree / "shared/cdpr/protocol/streams.py", ")\nSTATE = {c.name: c for c in STATE_COLUMNS}", COLUMN)
    _edit(tree / "shared/cdpr/protocol/messages.py", LAST, ATTRIBUTE)
    _edit(tree / "services/sim/cdpr_sim/core.py",
          "                     tuple(lengths.tolist()), tuple(self._tensions.tolist()), clamped)", PRODUCER)
    assert sorted(_changed(tree)) == ["services/sim/cdpr_sim/core.py", "shared/cdpr/protocol/messages.py",
                                      "shared/cdpr/protocol/streams.py"]  # two files besides the producer

    path = [str(tree / "shared"), *(str(p) for p in sorted((tree / "services").glob("*")))]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(path), "PYTHONDONTWRITEBYTECODE": "1"}
    rrd, mcap, converted = tmp_path / "e.rrd", tmp_path / "e.mcap", tmp_path / "c.mcap"
    run = subprocess.run([sys.executable, "-m", "cdpr", "run", "caroca_15kg", "--duration", "0.05", "--in-process",
                          "--quiet", "--rrd", str(rrd), "--mcap", str(mcap)],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    conv = subprocess.run([sys.executable, "-m", "cdpr", "convert", str(rrd), "--to", "mcap", "-o", str(converted)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert conv.returncode == 0, conv.stderr[-3000:]

    from rerun.chunk import RrdReader

    series: dict[str, dict[int, list[float]]] = {"actual/energy": {}, "actual/twist": {}}
    for chunk in RrdReader(str(rrd)).stream().to_chunks():
        entity = chunk.entity_path.lstrip("/")
        if entity in series and not chunk.is_static:
            batch = chunk.to_record_batch()
            for k, v in zip(batch.column("step").to_pylist(), batch.column("Scalars:scalars").to_pylist(),
                            strict=True):
                series[entity][k] = v
    mass = 15.0
    assert sorted(series["actual/energy"]) == list(range(51))
    for k, v in series["actual/twist"].items():
        assert series["actual/energy"][k][0] == pytest.approx(0.5 * mass * float(np.dot(v[:3], v[:3])), rel=1e-12)
    assert max(series["actual/energy"][k][0] for k in series["actual/energy"]) > 0.0  # the platform moved

    from mcap.reader import make_reader

    for file in (mcap, converted):
        with file.open("rb") as f:
            rows = [(schema, json.loads(message.data)) for schema, _, message in
                    make_reader(f).iter_messages(topics=["/platform/state"])]
        assert len(rows) == 51, file
        assert "energy" in json.loads(rows[0][0].data)["properties"], file
        assert [r["energy"] for _, r in rows] == pytest.approx([series["actual/energy"][k][0] for k in range(51)],
                                                               rel=1e-12, abs=0.0), file
