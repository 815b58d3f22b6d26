"""The README: a drone builder's first screen, links that lead somewhere, figures that scripts reproduce.

Issue 17: the first screen holds what a drone builder needs (the two commands, the test command,
the way to the Raspberry Pi set-up) and nothing about test workers or VM steal; every figure the
README keeps names the script in ``scripts/`` that measures it; its test command is what CI runs.
"""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
README = (REPO / "README.md").read_text(encoding="utf-8")


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"```.*?```", "", text, flags=re.S)  # '#' lines in code blocks are no headings
    return {_slug(m.group(1)) for m in re.finditer(r"^#{1,6} (.+)$", text, flags=re.M)}


def _first_screen() -> str:
    return README[: README.index("\n## ")]


def test_the_first_screen_is_for_a_drone_builder() -> None:
    top = _first_screen()
    assert 'pip install ".[plot]"' in top and "mavahrs demo" in top and "bash .ci/run" in top
    for lab_word in ("xdist", "-n 0", "steal", "worker", "µs"):
        assert lab_word not in top, f"{lab_word!r} on the README's first screen"
    assert len(top.splitlines()) <= 30
    assert "](#raspberry-pi-and-other-aarch64-boards)" in top  # the Pi set-up one click away


def test_the_test_command_is_what_ci_runs() -> None:
    ci = (REPO / ".ci" / "run").read_text(encoding="utf-8")
    assert "bash .ci/run" in _first_screen()
    assert re.search(r"^python -m pytest\b", ci, flags=re.M), ".ci/run no longer runs the test suite"


def test_every_link_leads_to_a_file_and_heading() -> None:
    own = _anchors(REPO / "README.md")
    for target in re.findall(r"\]\(([^)\s]+)\)", README):
        if target.startswith(("http://", "https://")):
            continue
        path, _, anchor = target.partition("#")
        file = REPO / path if path else REPO / "README.md"
        assert file.exists(), f"README links to {path}, which does not exist"
        if anchor and file.suffix == ".md":
            anchors = own if not path else _anchors(file)
            assert anchor in anchors, f"README links to {target}: no such heading"


def test_every_figure_table_names_its_script() -> None:
    lines = README.splitlines()
    # a measured figure: a decimal number, or a number with a unit of angle, time or ratio
    figure = re.compile(r"\d\.\d|\d\s?(?:°|ns|µs|×| s\b|M messages/s|M samples/s)")
    tables: list[tuple[int, int]] = []
    i = 0
    while i < len(lines):
        if lines[i].startswith("|"):
            j = i
            while j < len(lines) and lines[j].startswith("|"):
                j += 1
            tables.append((i, j))
            i = j
        else:
            i += 1
    checked = 0
    for a, b in tables:
        block = "\n".join(lines[a:b])
        if not figure.search(block):
            continue  # a table of options, fields or commands
        context = "\n".join(lines[max(0, a - 12) : b])
        scripts = re.findall(r"scripts/(\w+\.py)", context)
        assert scripts, f"the table at README line {a + 1} has figures but names no script in scripts/"
        checked += 1
    assert checked >= 2  # the accuracy and the speed tables
    for name in set(re.findall(r"scripts/(\w+\.py)", README)):
        assert (REPO / "scripts" / name).exists(), f"README names scripts/{name}, which does not exist"


def test_the_places_left_for_later_sections() -> None:
    for mark in ("<!-- fleet -->", "<!-- status-page -->", "<!-- sitl-table -->", "<!-- accuracy-table -->"):
        assert README.count(mark) == 1, mark


def test_the_filter_pages_examples_run_on_the_readmes_arrays() -> None:
    """Each docs/filters/*.md example says it works on the README's ``gyro_rad_s, accel_m_s2, mag_ut``; run
    literally after the README's arrays (and the names its comment gives: ``dt``, a velocity), each must run
    and give unit quaternions (complementary's passed whole arrays to ``update()``: a ValueError)."""
    import numpy as np

    api = re.search(r"## Python API\n+```python\n(.*?)```", README, flags=re.S)
    assert api is not None
    setup = api.group(1).split("# a whole recording")[0]  # imports and the arrays
    ran = 0
    for page in sorted((REPO / "docs" / "filters").glob("*.md")):
        for code in re.findall(r"```python\n(.*?)```", page.read_text(encoding="utf-8"), flags=re.S):
            if "(as in the README's Python API)" not in code:
                continue
            env: dict[str, object] = {}
            exec(setup, env)  # noqa: S102 - the README's own example
            n = int(env["n"])  # type: ignore[call-overload]
            env.update(dt=1 / 400, vel_ned=np.zeros((n, 3)), vel=np.zeros((n, 3)))
            exec(code, env)  # noqa: S102 - the page's example, as a user copies it
            q = np.asarray(env["q"], dtype=float)
            assert np.allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-6), page.name
            ran += 1
    assert ran >= 4


def test_every_link_between_the_docs_leads_to_a_file_and_heading() -> None:
    """As the README's: docs/monitor.md linked navigation.md#the-second-opinion-monitor, a heading that is not
    there (the section is "The attitude monitor: a second opinion on the autopilot")."""
    for page in sorted((REPO / "docs").rglob("*.md")):
        text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if target.startswith(("http://", "https://", "mailto:")):
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            name = page.relative_to(REPO)
            assert file.exists(), f"{name} links to {path}, which does not exist"
            if anchor and file.suffix == ".md":
                assert anchor in _anchors(file), f"{name} links to {target}: no such heading"
