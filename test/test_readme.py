"""Every Python snippet of README.md (and of the user guide in docs/) runs as printed.

The snippets run in order, each in a fresh interpreter as a user would paste it, in one
temporary directory that sees the repository's ``config/`` and ``test/robots/`` under their
own names (the README's paths are relative to the repository root); a later snippet may use
what an earlier one wrote (the analysis reads the observer's estimates). The ROS snippet gets
a plant node in lockstep on a private domain, started here.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from ros_harness import domain_id, require

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
HANG_GUARD = 900.0  # [s] a guard against a hang (a cold numba cache compiles first), not a speed limit


def snippets(page: Path) -> list[str]:
    """The ```python blocks of a page (```py blocks are illustrations that need the user's own files)."""
    return re.findall(r"^```python\n(.*?)^```", page.read_text(), re.MULTILINE | re.DOTALL)


CASES = [pytest.param(page, k, id=f"{page.relative_to(REPO)}[{k}]") for page in PAGES
         for k in range(len(snippets(page)))]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    work = tmp_path_factory.mktemp("readme")
    for name in ("config", "test"):
        (work / name).symlink_to(REPO / name)
    return work


def run(code: str, cwd: Path, env: dict[str, str] | None = None) -> str:
    proc = subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=HANG_GUARD)
    assert proc.returncode == 0, f"{code}\n--- stdout\n{proc.stdout}\n--- stderr\n{proc.stderr}"
    return proc.stdout


def test_the_readme_has_a_snippet_for_each_job() -> None:
    code = "\n".join(snippets(REPO / "README.md"))
    for call in ("epd.load_model", ".urdf", ".xml", "epd.simulate", "torque_command", "epd.observe", "epd.analyze"):
        assert call in code, call


@pytest.mark.parametrize(("page", "k"), CASES)
def test_snippet_runs(page: Path, k: int, workdir: Path) -> None:
    code = snippets(page)[k]
    if "rclpy" not in code:
        run(code, workdir)
        return
    require("rclpy")
    from elastic_pm_dyn.ros.demos.processes import NodeProcess, ros_env

    env = ros_env(domain_id(41))
    plant = NodeProcess("plant", "elastic_pm_dyn.ros.plant.node", ["-p", "sync_mode:=lockstep"], env,
                        workdir / "logs")
    try:
        out = run(code, workdir, env)
    finally:
        plant.stop()
    assert out.startswith("100 states"), out
    assert "Traceback" not in (workdir / "logs" / "plant.log").read_text()


# Pages the README links that other branches write (issues #25, #26, #28 and the observer loop):
# drop each name once its page is merged, so that a dead link fails here.
PENDING_PAGES: set[str] = set()  # pages another branch adds (linked before they are merged)


def github_anchor(heading: str) -> str:
    """The id GitHub gives a Markdown heading: lower case, punctuation but - and _ dropped, spaces -."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def test_every_relative_link_of_the_readme_docs_and_bench_resolves() -> None:
    pages = [*PAGES, *sorted((REPO / "bench").rglob("README*.md"))]
    dead = []
    for page in pages:
        text = re.sub(r"^```.*?^```", "", page.read_text(), flags=re.MULTILINE | re.DOTALL)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if target.startswith(("http://", "https://", "mailto:")):
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if str(file.relative_to(REPO)) in PENDING_PAGES:
                continue
            if not file.exists():
                dead.append(f"{page.relative_to(REPO)}: {target}")
            elif anchor and file.suffix == ".md":
                headings = re.findall(r"^#+ (.*)$", file.read_text(), re.MULTILINE)
                if anchor not in {github_anchor(h) for h in headings}:
                    dead.append(f"{page.relative_to(REPO)}: {target} (no such heading)")
    assert not dead, "\n".join(dead)
