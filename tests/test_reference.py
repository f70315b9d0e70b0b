"""docs/scenarios.md: every key of a scenario file, generated from the models that validate it, so that the page
cannot drift from the loader; and the rule of where a session starts, stated and said when it matters."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from cdpr.config.loading import read_yaml, resolve
from cdpr.config.reference import reference_markdown, rows
from cdpr.config.scenario import ScenarioSpec, load_scenario, shipped_scenarios
from conftest import CDPR, ROOT

PAGE = ROOT / "docs" / "scenarios.md"


def test_the_page_is_what_the_models_say() -> None:
    """A key added to (or changed in) the models and not to the page fails here: `cdpr scenarios --reference >
    docs/scenarios.md` writes it again."""
    assert PAGE.read_text(encoding="utf-8") == reference_markdown(), \
        "docs/scenarios.md is not `cdpr scenarios --reference`'s output: run it again"
    assert "docs/scenarios.md" in (ROOT / "README.md").read_text(encoding="utf-8")  # the README links it


def test_every_key_says_what_it_is_and_every_shipped_key_is_there() -> None:
    every = list(rows(ScenarioSpec))
    assert [r.key for r in every if not r.description] == []  # its unit, its meaning: a description each
    known = {r.key for r in every}
    free = {r.key for r in every if r.type == "mapping"}  # a method's options: its own keys

    def keys(value: Any, prefix: str = "") -> set[str]:
        out: set[str] = set()
        if isinstance(value, dict):
            for k, v in value.items():
                out |= {f"{prefix}{k}"} | (set() if f"{prefix}{k}" in free else keys(v, f"{prefix}{k}."))
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            for item in value:
                out |= keys(item, prefix.removesuffix(".") + "[].")
        return out

    for name in shipped_scenarios():
        used = keys(read_yaml(resolve(name, "scenarios", "scenario")))
        assert used - known == set(), name


def _shifted(tmp_path: Path, dx: float) -> Path:
    spec = yaml.safe_load((ROOT / "shared" / "cdpr" / "scenarios" / "caroca_15kg.yaml").read_text(encoding="utf-8"))
    spec["trajectory"]["waypoints"][0]["position"][0] += dx
    spec["robot"] = "caroca"
    path = tmp_path / "shifted.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False), encoding="utf-8")
    return path


def test_a_session_starts_at_its_first_waypoint_and_says_so_when_that_is_not_home(tmp_path: Path) -> None:
    """The rule of docs/scenarios.md: a session starts at `initial`, else at the trajectory's first pose — not at
    the robot's home; `cdpr run` says so in one line (even with --quiet) when the two differ."""
    import subprocess

    from conftest import last_json_line

    path = _shifted(tmp_path, 0.1)
    s = load_scenario(path)
    assert list(s.initial_position) == [1.0, 0.9, 0.2]  # the first waypoint, not home's 0.9
    note = ("shifted starts at its trajectory's first pose, [1, 0.9, 0.2] m, not the robot's home: 0.1 m from it (a "
            "scenario starts at `initial`, else at its trajectory's first pose; docs/scenarios.md)")
    assert s.start_note() == note.replace("shifted", s.name)
    run = subprocess.run([*CDPR, "run", str(path), "--in-process", "--duration", "0.01", "--quiet"],
                         capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 0, run.stderr[-2000:]
    assert f"[cdpr] {note.replace('shifted', s.name)}" in run.stderr.splitlines()
    assert last_json_line(run.stdout)["steps"] == 10
    assert load_scenario("caroca_15kg").start_note() is None  # at home: nothing said
