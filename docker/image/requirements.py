"""Print the requirements of the cdpr package and some of its extras, from pyproject.toml, one a line.

    python requirements.py pyproject.toml stack        # the base dependencies and stack's
    python requirements.py pyproject.toml record plots # ... and those of several extras

An extra may name others (``cdpr[stack]``): they are followed. The Dockerfile installs these before it
copies the sources, so that its dependency layers are built again only when pyproject.toml changes.
"""

from __future__ import annotations

import re
import sys
import tomllib


def requirements(pyproject: str, extras: list[str]) -> list[str]:
    with open(pyproject, "rb") as f:
        project = tomllib.load(f)["project"]
    name, optional = project["name"], project.get("optional-dependencies", {})
    own = re.compile(rf"^{re.escape(name)}\[([^\]]+)\]\s*$")  # cdpr[stack]: another extra of this package
    out: list[str] = list(project.get("dependencies", []))
    todo, seen = list(extras), set()
    while todo:
        extra = todo.pop(0)
        if extra in seen:
            continue
        if extra not in optional:
            sys.exit(f"requirements.py: {pyproject} has no extra {extra!r} (it has {', '.join(optional)})")
        seen.add(extra)
        for req in optional[extra]:
            m = own.match(req)
            if m:
                todo.extend(e.strip() for e in m.group(1).split(","))
            elif req not in out:
                out.append(req)
    return out


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    print("\n".join(requirements(sys.argv[1], sys.argv[2:])))
