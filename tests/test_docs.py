"""The documentation runs: its code and its site.

1. Every ```python block of ``README.md`` and of ``docs/**/*.md`` executes: a file's blocks run in
   order, in one fresh namespace and a working directory of its own (``MPLBACKEND=Agg``), and a
   failure names the file and the line of the block.  The files run in :data:`DOC_GROUPS`
   subprocesses, one after another in each (a program one file compiles, the next reuses, as
   in a user's session).  Shell blocks (```bash, ```console) are not run.
2. The site builds: ``mkdocs build --strict`` with the four tutorials executed at build time and
   rendered with their outputs and plots, and the API reference generated from the docstrings of
   ``solvers``, ``frenet``, ``mmdopt`` and ``mmdopt.bench``.  A broken cross-reference, a
   docstring mkdocstrings cannot parse, a missing page or a notebook cell that raises fails the
   build (``strict: true``, ``allow_errors: false`` in ``mkdocs.yml``).  The notebooks run at their
   small sizes (``MMDOPT_NB_SMALL=1``).
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SITE_MODULES = ("mkdocs", "material", "mkdocstrings_handlers.python", "mkdocs_jupyter", "ipykernel")
BLOCK_TIMEOUT_S = 1800  # one group's files: first-call compilations on a loaded 2-core machine
#: the subprocesses the documentation's files are shared among (one per test worker)
DOC_GROUPS = 2


# ---------------------------------------------------------------- 1. the Python blocks run
_FENCE = re.compile(
    r"^(?P<indent>[ \t]*)```(?P<lang>[\w+-]*)[^\n]*\n(?P<body>.*?)^(?P=indent)```", re.M | re.S
)


def python_blocks(path: Path) -> list[tuple[int, str]]:
    """``(line, source)`` of every ```python block of a Markdown file, in order (``line``: the
    1-based line of the opening fence)."""
    text = path.read_text(encoding="utf-8")
    out = []
    for m in _FENCE.finditer(text):
        if m["lang"] != "python":
            continue
        indent = len(m["indent"])
        body = "".join(line[indent:] for line in m["body"].splitlines(keepends=True))
        out.append((text.count("\n", 0, m.start()) + 1, body))
    return out


def _doc_files() -> list[Path]:
    files = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
    return [f for f in files if python_blocks(f)]


#: runs in the subprocess: file after file, every block of one file in one namespace and in a
#: folder of its own, each block compiled under the name ``FILE:LINE`` so that a traceback points
#: at the block
_RUNNER = """
import json, os, sys, traceback
root = os.getcwd()
for i, (name, blocks) in enumerate(json.load(open(sys.argv[1], encoding="utf-8"))):
    os.chdir(os.path.join(root, f"file{i}"))
    ns = {"__name__": "__main__"}
    for line, source in blocks:
        try:
            exec(compile(source, f"{name}:{line}", "exec"), ns)
        except BaseException:
            traceback.print_exc()
            print(f"DOCS-BLOCK-FAILED {name}, the block at line {line}", file=sys.stderr)
            sys.exit(1)
    if "matplotlib.pyplot" in sys.modules:
        sys.modules["matplotlib.pyplot"].close("all")
"""


def _doc_group(i: int) -> list[Path]:
    return _doc_files()[i::DOC_GROUPS]


@pytest.mark.slow
@pytest.mark.parametrize(
    "group",
    range(DOC_GROUPS),
    ids=lambda i: "+".join(p.stem for p in _doc_group(i)),
)
def test_every_python_block_of_the_docs_runs(group, tmp_path):
    files = _doc_group(group)
    todo = []
    for i, path in enumerate(files):
        (tmp_path / f"file{i}").mkdir()
        todo.append([str(path.relative_to(REPO)).replace(os.sep, "/"), python_blocks(path)])
    (tmp_path / "_blocks.json").write_text(json.dumps(todo), "utf-8")
    (tmp_path / "_run_blocks.py").write_text(_RUNNER, "utf-8")
    env = dict(os.environ, MPLBACKEND="Agg")
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if "PYTHONPATH" in env else "")
    proc = subprocess.run(
        [sys.executable, "_run_blocks.py", "_blocks.json"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=BLOCK_TIMEOUT_S,
    )
    failed = re.search(r"DOCS-BLOCK-FAILED (.*)", proc.stderr)
    where = failed[1] if failed else ", ".join(name for name, _ in todo)
    assert proc.returncode == 0, f"{where} failed:\n{proc.stderr[-6000:]}"


def test_every_documentation_file_with_python_is_in_a_group():
    groups = [p for i in range(DOC_GROUPS) for p in _doc_group(i)]
    assert sorted(groups) == sorted(_doc_files()) and len(groups) == len(set(groups))


def test_readme_and_docs_blocks_are_found():
    """The block extractor sees the README's Python blocks (a guard against a silent regex)."""
    blocks = python_blocks(REPO / "README.md")
    assert len(blocks) >= 2 and all(src.strip() for _, src in blocks)


def _markdown_files() -> list[Path]:
    return [REPO / "README.md", REPO / "CHANGELOG.md", *sorted((REPO / "docs").rglob("*.md"))]


def test_the_docs_teach_rather_than_keep_a_diary():
    """Results pages state today's figures with their provenance; the history lives in
    ``CHANGELOG.md``.  No page narrates the work that made it (``DIARY``), and equations are
    cited from the paper."""
    from .test_architecture import DIARY

    pattern = re.compile(DIARY.pattern + r"|\bthis change\b")
    hits = [
        f"{f.relative_to(REPO)}:{i}: {line.strip()[:80]}"
        for f in _markdown_files()
        for i, line in enumerate(f.read_text(encoding="utf-8").splitlines(), 1)
        if pattern.search(line)
    ]
    assert not hits, hits


def test_docstring_markup_becomes_markdown():
    """``docs/hooks.py``'s griffe extension: Sphinx roles become links (or code), a list after a
    paragraph gets its blank line, ``::`` blocks become fences, reST tables Markdown tables, and
    numpy items written as sentences move into the description column."""
    pytest.importorskip("griffe")
    pytest.importorskip("mkdocs")
    spec = importlib.util.spec_from_file_location("_docs_hooks", REPO / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    fields = hooks.convert_docstring("Fields.\n\nego : the ego\nroad : the road", ["mmdopt"])
    assert fields.endswith("- `ego`: the ego\n- `road`: the road")
    text = "\n".join(
        [
            "Uses :func:`plan` and :class:`~mmdopt.api.Road`, not :class:`NoSuchThing`.",
            "Steps:",
            "1. first",
            "2. second",
            "",
            "Example::",
            "",
            "    x = 1",
            "",
            "=====  =====",
            "a      b",
            "=====  =====",
            "``1``  two",
            "=====  =====",
            "",
            "Parameters",
            "----------",
            "road : :class:`Road` of the plan",
            "",
            "Raises",
            "------",
            "ValueError naming the argument",
        ]
    )
    out = hooks.convert_docstring(text, ["mmdopt.api", "mmdopt"])
    assert '<autoref identifier="mmdopt.api.plan" slug="mmdopt.plan" optional>' in out
    assert "<code>plan()</code>" in out and "<code>Road</code></autoref>" in out
    assert "`NoSuchThing`" in out and ":class:" not in out and ":func:" not in out
    assert "Steps:\n\n1. first\n2. second" in out
    assert "Example:\n\n```text\nx = 1\n```" in out
    assert "| a | b |\n|---|---|\n| ``1`` | two |" in out
    assert "road\n    <autoref" in out  # prose moved out of the type slot
    assert "ValueError\n    naming the argument" in out


# ------------------------------------------------------------------------ 2. the site builds
def _site_extras_missing() -> str | None:
    for mod in SITE_MODULES:
        try:
            if importlib.util.find_spec(mod) is None:
                return mod
        except ModuleNotFoundError:  # a missing parent package of a dotted name
            return mod
    return None


TUTORIALS = (
    "01_quickstart",
    "02_qp_backends",
    "03_reduced_set",
    "04_projection_research",
    "05_learning_through_the_projection",
)
BUILD_TIMEOUT_S = 1200  # five notebooks executed on a loaded 2-core CI machine


API_NAMES = {
    "solvers": ["solvers.QP", "solvers.solve", "solvers.Solution"],
    "frenet": ["frenet.ReferencePath", "frenet.ProjectionProblem", "frenet.EgoState"],
    "mmdopt": ["mmdopt.plan", "mmdopt.Plan", "mmdopt.Road", "mmdopt.select_reduced_set"],
    "bench": ["mmdopt.bench.scenes.make_scene", "mmdopt.bench.results.load_results"],
}


NAV_PAGES = (
    ".",
    "getting-started",
    "architecture",
    "howto/qp-backend",
    "howto/predictor",
    "howto/receding",
    "howto/ray",
    "howto/ngsim",
    "experiments/synthetic",
    "experiments/frontier",
    "experiments/ngsim",
    "experiments/highway",
    "experiments/qp-backends",
    "changelog",
)


def _build(out: Path) -> None:
    env = dict(os.environ)
    env.update(MMDOPT_NB_SMALL="1", MPLBACKEND="Agg", NO_MKDOCS_2_WARNING="1")
    # the notebook kernels import the packages of this checkout even when it is not installed
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if "PYTHONPATH" in env else "")
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", "mkdocs.yml", "-d", str(out)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=BUILD_TIMEOUT_S,
    )
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stdout}\n{proc.stderr}"


@pytest.mark.slow
def test_site_builds_strict_with_executed_tutorials_and_api_reference(tmp_path):
    """One build (one test, so that parallel test workers do not each build the site): every
    tutorial rendered with its final checks and a plot, every API page documenting its public
    names with the docstrings' Sphinx roles rendered, every page of the navigation present."""
    missing = _site_extras_missing()
    if missing:
        pytest.skip(f"{missing} is not installed (pip install -e '.[docs]')")
    _build(tmp_path)
    problems = []
    for name in TUTORIALS:
        html = (tmp_path / "notebooks" / name / "index.html").read_text(encoding="utf-8")
        if "CHECKS PASSED" not in html:
            problems.append(f"{name}: the executed notebook's final checks are not shown")
        if "data:image/png" not in html:
            problems.append(f"{name}: no plot rendered")
    for page, names in API_NAMES.items():
        html = (tmp_path / "api" / page / "index.html").read_text(encoding="utf-8")
        missing = [n for n in names if f'id="{n}"' not in html]
        problems += [f"API page {page} does not document {n}" for n in missing]
        roles = sorted(set(re.findall(r":(?:func|class|meth|mod|data|attr):", html)))
        if roles:
            problems.append(f"API page {page} shows raw Sphinx roles {roles}")
        if "&lt;autoref" in html:
            problems.append(f"API page {page} shows an escaped cross-reference")
    for page in NAV_PAGES:
        if not (tmp_path / page / "index.html").exists():
            problems.append(f"page {page} missing")
    assert not problems, problems
