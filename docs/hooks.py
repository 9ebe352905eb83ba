"""Build-time helpers of the documentation site (``mkdocs.yml`` loads this file twice).

1. As an MkDocs hook (``hooks:``): the tutorials live in ``notebooks/``, beside the code they
   test.  :func:`on_files` adds each ``notebooks/*.ipynb`` to the site (as
   ``notebooks/<name>.ipynb``, outside ``docs_dir``) before ``mkdocs-jupyter`` turns notebooks into
   pages (it executes them at build time: ``execute: true`` in ``mkdocs.yml``).
2. As a griffe extension of mkdocstrings (``extensions: [docs/hooks.py:DocstringMarkup]``): the
   docstrings are numpy style with a few reStructuredText habits that Markdown does not know.
   :class:`DocstringMarkup` rewrites them when the API reference is built (the source files are
   not touched):

   * Sphinx roles (``:func:`x```, ``:class:``, ``:meth:``, ``:mod:``, ``:data:``, ``:attr:``,
     ``:obj:``, ``:exc:``; ``~`` shortens the shown name) become links to the documented object
     when the name resolves (relative to the docstring's class, module and package, like Sphinx),
     inline code otherwise;
   * a list item that follows a paragraph line gets the blank line Markdown needs to see a list,
     and ``name : text`` lines outside a numpy section (a dataclass's fields) become a list;
   * ``text::`` followed by an indented block becomes ``text:`` and a fenced code block;
   * simple reST tables (``====  ====`` rules) become Markdown tables.
"""

from __future__ import annotations

import builtins
import importlib
import re
from pathlib import Path
from typing import Any

import griffe
from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

REPO = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------ MkDocs hook
@event_priority(100)  # before mkdocs-jupyter's on_files (default priority 0)
def on_files(files, config):
    for nb in sorted((REPO / "notebooks").glob("*.ipynb")):
        # a real source file (src_dir set): mkdocs-jupyter's wrapper reads ``abs_src_path``
        files.append(
            File(
                f"notebooks/{nb.name}",
                src_dir=str(REPO),
                dest_dir=config.site_dir,
                use_directory_urls=config.use_directory_urls,
            )
        )
    return files


# ------------------------------------------------------------------ griffe: docstring markup
_ROLE = re.compile(
    r":(?:py:)?(?P<kind>func|class|meth|mod|data|attr|obj|exc|const):"
    r"`(?P<mod>[~!]?)(?P<target>[^`<>\s]+)`"
)
_ITEM = re.compile(r"^(?P<indent>\s*)(?:[-*+]|\d+[.)])\s+\S")
_RULE = re.compile(r"^\s*=+(?:\s+=+)+\s*$")
_FENCE = re.compile(r"^\s*(```|~~~)")


def _runtime(path: str) -> Any:
    """The Python object at a dotted ``path`` (the longest importable module, then attributes),
    or ``None``."""
    parts = path.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except Exception:  # noqa: BLE001 - any import failure: try a shorter module path
            continue
        try:
            for name in parts[i:]:
                obj = getattr(obj, name)
        except AttributeError:
            return None
        return obj
    return None


def _canonical(found: Any, path: str) -> str:
    """Where ``found`` (reached as ``path``) is defined: ``module.qualname`` for modules, classes
    and functions; ``path`` itself for data and attributes."""
    if isinstance(found, type(builtins)):
        return found.__name__
    mod, qual = getattr(found, "__module__", None), getattr(found, "__qualname__", None)
    if isinstance(mod, str) and isinstance(qual, str) and "<" not in qual:
        return f"{mod}.{qual}"
    return path


def _public_alias(found: Any, canonical: str) -> str | None:
    """The shortest path a package re-exports ``found`` under (``mmdopt.plan`` for
    ``mmdopt.api.plan``; ``mmdopt.Plan.to_dict`` for a method), or ``None``."""
    mod, qual = getattr(found, "__module__", None), getattr(found, "__qualname__", None)
    if not (isinstance(mod, str) and isinstance(qual, str)) or "<" in qual:
        return None
    head = qual.split(".")[0]
    parts = mod.split(".")
    for i in range(1, len(parts)):
        package = ".".join(parts[:i])
        obj = _runtime(f"{package}.{head}")
        if obj is not None and obj is _runtime(f"{mod}.{head}"):
            alias = f"{package}.{qual}"
            return alias if alias != canonical else None
    return None


def _resolve(target: str, scopes: list[str]) -> tuple[str, str] | None:
    """``(canonical path, second path)`` of a role's target, looked up as written and then
    relative to each scope (innermost first), like Sphinx; the second path is the one it was
    reached by, or else a package's re-export.  ``None`` when nothing matches."""
    if target.startswith("."):  # relative to the module's package: ``:mod:`.metric```
        target = target.lstrip(".")
        candidates = [f"{s}.{target}" for s in scopes[1:]]
    else:
        candidates = [target] + [f"{s}.{target}" for s in scopes]
    for path in candidates:
        if path.split(".")[0] not in {"solvers", "frenet", "mmdopt"}:
            if path in dir(builtins):  # :class:`ValueError`: the Python docs are not linked
                return None
            continue
        found = _runtime(path)
        if found is not None:
            canonical = _canonical(found, path)
            if path == canonical:  # the site may document it where a package re-exports it
                path = _public_alias(found, canonical) or path
            return canonical, path
    return None


def _role_to_markdown(match: re.Match, scopes: list[str]) -> str:
    target, mod = match["target"], match["mod"]
    shown = target.lstrip(".").split(".")[-1] if mod == "~" else target.lstrip(".")
    if match["kind"] in ("func", "meth"):
        shown += "()"
    hit = _resolve(target, scopes) if mod != "!" else None
    if hit is None:
        return f"`{shown}`"
    canonical, reached = hit
    # autorefs tries ``identifier`` then ``slug``: the canonical path and the path as written
    # (e.g. ``mmdopt.plan``, where the API page documents the re-export); ``optional``: an
    # object the site does not document renders as code, without a warning
    slug = f' slug="{reached}"' if reached != canonical else ""
    return f'<autoref identifier="{canonical}"{slug} optional><code>{shown}</code></autoref>'


def _scopes(obj: griffe.Object) -> list[str]:
    """Lookup scopes of a docstring, innermost first: the object (a class or module), its
    enclosing classes and module, then each parent package."""
    out: list[str] = []
    cur: griffe.Object | None = obj if obj.is_class or obj.is_module else obj.parent
    while cur is not None:
        out.append(cur.path)
        cur = cur.parent
    return out


def _rst_table(lines: list[str]) -> list[str]:
    """A simple reST table (``===`` rule, header, rule, rows, rule) as a Markdown table; rows
    whose first cell is empty continue the row above."""
    rule = lines[0]
    spans = [(m.start(), m.end()) for m in re.finditer(r"=+", rule)]

    def cells(line: str) -> list[str]:
        out = []
        for j, (a, _) in enumerate(spans):
            b = spans[j + 1][0] if j + 1 < len(spans) else len(line)
            out.append(line[a:b].strip())
        return out

    rows: list[list[str]] = []
    header: list[str] | None = None
    for line in lines[1:]:
        if _RULE.match(line):
            if header is None and rows:
                header, rows = [" ".join(c) for c in zip(*rows, strict=True)], []
            continue
        if not line.strip():
            continue
        c = cells(line)
        if rows and not c[0] and header is not None:
            rows[-1] = [f"{p} {q}".strip() for p, q in zip(rows[-1], c, strict=True)]
        else:
            rows.append(c)
    header = header or [""] * len(spans)
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(spans)]
    md += ["| " + " | ".join(r) + " |" for r in rows]
    return ["", *md, ""]


_SECTION_KIND = {
    "parameters": "params",
    "other parameters": "params",
    "attributes": "params",
    "returns": "returns",
    "yields": "returns",
    "raises": "raises",
    "warns": "raises",
}
_DASHES = re.compile(r"^\s*-{3,}\s*$")
_SIMPLE_TYPE = re.compile(r"^[\w.]+(?:\[[\w., |\[\]]*\])?(?: \| [\w.]+(?:\[[\w., |\[\]]*\])?)*$")
_ROLE_ONLY = re.compile(r"^:(?:py:)?\w+:`[~!]?([^`]+)`$")
_FIELD = re.compile(r"^(\*{0,2}[A-Za-z_]\w*(?:, \*{0,2}[A-Za-z_]\w*)*) : (\S.*)$")


def _as_type(text: str) -> str | None:
    """``text`` as a type griffe can parse (``float``, ``int | None``, a role around a name), or
    ``None`` when it is prose."""
    text = text.strip()
    m = _ROLE_ONLY.match(text)
    if m:
        text = m[1]
    return text if _SIMPLE_TYPE.match(text) else None


def _numpy_items(lines: list[str]) -> list[str]:
    """Numpy sections whose item lines hold prose where griffe expects a type (``ego :
    :class:`EgoState` in the Frenet frame``, ``Returns`` / ``Raises`` items written as a
    sentence) rewritten so that the prose is the item's description: the rendered tables then
    show the signature's annotation as the type and the prose, with working links, beside it."""
    out: list[str] = []
    kind: str | None = None
    prose = False  # the last item of a Returns/Raises section is a sentence still going on
    in_fence = False
    for k, line in enumerate(lines):
        nxt = lines[k + 1] if k + 1 < len(lines) else ""
        if _FENCE.match(line):
            in_fence = not in_fence
        if in_fence or _FENCE.match(line):
            out.append(line)
            continue
        if line.strip() and not line.startswith(" ") and _DASHES.match(nxt):
            kind = _SECTION_KIND.get(line.strip().lower())
            out.append(line)
            prose = False
            continue
        if kind is None and not line.startswith(" "):
            # ``name : text`` lines outside a numpy section (a class's fields, a module's
            # arguments) as a list, each with its continuation lines
            m = _FIELD.match(line)
            if m:
                names = ", ".join(f"`{n}`" for n in m[1].split(", "))
                out.append(f"- {names}: {m[2]}")
                continue
        if kind is None or not line.strip() or line.startswith(" ") or _DASHES.match(line):
            out.append(line)
            prose = prose and bool(line.strip())
            continue
        if prose and kind in ("returns", "raises"):
            out.append("    " + line)  # an unindented second line of the same sentence
            continue
        if kind == "params":
            m = re.match(r"^(\*{0,2}\w+(?:, \*{0,2}\w+)*) : (.+)$", line)
            if m and not m[2].startswith("{"):
                typ = _as_type(m[2])
                out += [f"{m[1]} : {typ}"] if typ else [m[1], "    " + m[2]]
                continue
        elif kind == "returns":
            m = re.match(r"^(\w+) : (.+)$", line)
            if m:
                typ = _as_type(m[2])
                out += [f"{m[1]} : {typ}"] if typ else [f"{m[1]} :", "    " + m[2]]
                continue
            typ = _as_type(line)
            out += [typ] if typ else [":", "    " + line]
            prose = typ is None
            continue
        elif kind == "raises":
            m = re.match(r"^(:\w+:`[^`]+`|[\w.]+)[,:;]?(?:\s+(.*))?$", line)
            if m and _as_type(m[1]):
                out.append(_as_type(m[1]) or "")
                if m[2]:
                    out.append("    " + m[2])
                prose = bool(m[2])
                continue
        out.append(line)
    return out


def convert_docstring(text: str, scopes: list[str]) -> str:
    """A numpy/reST-flavoured docstring as the Markdown mkdocstrings renders (see the module
    docstring)."""
    lines = _numpy_items(text.splitlines())
    out: list[str] = []
    i, in_fence = 0, False
    while i < len(lines):
        line = lines[i]
        if _FENCE.match(line):
            in_fence = not in_fence
            out.append(line)
            i += 1
            continue
        if in_fence:
            out.append(line)
            i += 1
            continue
        # simple reST table: a rule line, then up to the third rule line
        if _RULE.match(line):
            n_rules, j = 1, i + 1
            while j < len(lines) and n_rules < 3:
                n_rules += bool(_RULE.match(lines[j]))
                j += 1
            if n_rules == 3:
                out += _rst_table(lines[i:j])
                i = j
                continue
        # ``text::`` + indented block: a fenced code block
        if line.rstrip().endswith("::") and not line.strip().startswith(".."):
            base = len(line) - len(line.lstrip())
            j = i + 1
            while j < len(lines) and not lines[j].strip():
                j += 1
            block_end = j
            while block_end < len(lines) and (
                not lines[block_end].strip()
                or len(lines[block_end]) - len(lines[block_end].lstrip()) > base
            ):
                block_end += 1
            if j < block_end:
                block = lines[j:block_end]
                while block and not block[-1].strip():
                    block.pop()
                cut = min(len(b) - len(b.lstrip()) for b in block if b.strip())
                head = line.rstrip()[:-2].rstrip()
                if head.strip():
                    out.append(_ROLE.sub(lambda m: _role_to_markdown(m, scopes), head + ":"))
                out += ["", " " * base + "```text"]
                out += [(" " * base + b[cut:]) if b.strip() else "" for b in block]
                out += [" " * base + "```", ""]
                i = block_end
                continue
        # a list item right after a paragraph line: Markdown needs a blank line before it
        m = _ITEM.match(line)
        if m and out and out[-1].strip() and not _ITEM.match(out[-1]):
            prev_indent = len(out[-1]) - len(out[-1].lstrip())
            if prev_indent <= len(m["indent"]) and not out[-1].lstrip().startswith("|"):
                out.append("")
        out.append(_ROLE.sub(lambda mm: _role_to_markdown(mm, scopes), line))
        i += 1
    return "\n".join(out)


class DocstringMarkup(griffe.Extension):
    """Rewrite every docstring of a loaded package with :func:`convert_docstring`."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        seen: set[str] = set()
        stack: list[griffe.Object] = [pkg]
        while stack:
            obj = stack.pop()
            if obj.path in seen:
                continue
            seen.add(obj.path)
            if obj.docstring is not None:
                obj.docstring.value = convert_docstring(obj.docstring.value, _scopes(obj))
                obj.docstring.__dict__.pop("parsed", None)  # parsed lazily from the new text
            stack += [m for m in obj.members.values() if not m.is_alias]
