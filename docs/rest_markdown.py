"""The reST of this project's docstrings as Markdown, for the documentation site.

The docstrings are Google style with reST inline markup, as Sphinx reads them:
``literal``, roles such as :class:`~auv_envs.tasks.docking.optics.WaterOptics`, ``::``
literal blocks and, in the docking environment, simple tables. MkDocs renders
Markdown, so :func:`to_markdown` rewrites exactly those four constructs and
leaves everything else (paragraphs, ``*`` lists, ``**bold**``, Google sections)
as it is. A role becomes a cross-reference that links to the API reference when
the object is documented there and stays plain code otherwise (mkdocs-autorefs'
optional references), so the build never fails on a name the reference leaves out.

Used twice: by :mod:`env_pages` on the environment classes' docstrings, and as a
griffe extension (:class:`RestDocstrings`, listed in ``mkdocs.yml``) on every
docstring mkdocstrings renders.
"""

from __future__ import annotations

import html
import re
from collections.abc import Callable

import griffe

ROLE = re.compile(r":(?:py:)?(?:class|func|meth|data|mod|attr|exc|obj):`(~?)([^`]+)`")
LITERAL = re.compile(r"``(.+?)``")
TABLE_BORDER = re.compile(r"^\s*=+(?:\s+=+)+\s*$")


def to_markdown(text: str, resolve: Callable[[str], str] = str) -> str:
    """``text`` (a docstring, dedented) with its reST constructs in Markdown.

    Args:
        text: the docstring.
        resolve: a role's target as written -> its full dotted path (the name as
            written when it cannot be resolved).
    """
    lines = _literal_blocks(_tables(text.splitlines()))
    out, fenced = [], False
    for line in lines:
        if line.lstrip().startswith("```"):
            fenced = not fenced
        out.append(line if fenced else _inline(line, resolve))
    return "\n".join(out)


def _inline(line: str, resolve: Callable[[str], str]) -> str:
    def role(match: re.Match) -> str:
        short, target = match.group(1) == "~", match.group(2)
        title = target.rsplit(".", 1)[-1] if short else target
        return (f'<autoref identifier="{html.escape(resolve(target))}" optional>'
                f"<code>{html.escape(title)}</code></autoref>")

    line = LITERAL.sub(lambda m: f"`{m.group(1)}`", line)
    return ROLE.sub(role, line)


def _tables(lines: list[str]) -> list[str]:
    """reST simple tables (``===`` borders) -> Markdown tables."""
    out, i = [], 0
    while i < len(lines):
        if not TABLE_BORDER.match(lines[i]):
            out.append(lines[i])
            i += 1
            continue
        border = lines[i]
        spans = [m.span() for m in re.finditer(r"=+", border)]
        indent = border[: spans[0][0]]
        rows, header, j = [], None, i + 1
        while j < len(lines):
            line = lines[j]
            if TABLE_BORDER.match(line):
                j += 1
                closing = j == len(lines) or not lines[j].strip()
                if header is None and not closing:  # the border under the header
                    header, rows = rows, []
                    continue
                break
            cells = [line[a:b if k < len(spans) - 1 else None].strip()
                     for k, (a, b) in enumerate(spans)]
            if rows and not cells[0]:  # reST: a blank first column continues the row above
                rows[-1] = [f"{old} {new}".strip()
                            for old, new in zip(rows[-1], cells, strict=True)]
            elif any(cells):
                rows.append(cells)
            j += 1
        header = [" ".join(parts) for parts in zip(*header, strict=True)] if header else rows.pop(0)
        out.append("")
        out.append(indent + "| " + " | ".join(_cell(c) for c in header) + " |")
        out.append(indent + "|" + "---|" * len(header))
        out.extend(indent + "| " + " | ".join(_cell(c) for c in row) + " |" for row in rows)
        out.append("")
        i = j
    return out


def _cell(text: str) -> str:
    # A pipe outside a code span would split the Markdown cell.
    parts = re.split(r"(``.+?``)", text)
    return "".join(p if p.startswith("``") else p.replace("|", r"\|") for p in parts)


def _literal_blocks(lines: list[str]) -> list[str]:
    """A paragraph ending in ``::`` and the indented block after it -> a fenced block.

    The fence sits at the paragraph's margin, or four spaces in when the paragraph
    is inside a list item (Python-Markdown's list indentation).
    """
    out, i = [], 0
    while i < len(lines):
        line = lines[i]
        if not line.rstrip().endswith("::"):
            out.append(line)
            i += 1
            continue
        stripped = line.rstrip()[:-2].rstrip()
        margin = len(line) - len(line.lstrip())
        if stripped.strip():
            out.append(stripped + ":")
        j = i + 1
        while j < len(lines) and not lines[j].strip():
            j += 1
        block = []
        while j < len(lines) and (not lines[j].strip()
                                  or len(lines[j]) - len(lines[j].lstrip()) > margin):
            block.append(lines[j])
            j += 1
        while block and not block[-1].strip():
            block.pop()
        if not block:
            i += 1
            continue
        depth = min(len(b) - len(b.lstrip()) for b in block if b.strip())
        fence = " " * (4 if margin or _in_list(out) else 0)
        out.append("")
        out.append(fence + "```text")
        out.extend(fence + b[depth:] if b.strip() else "" for b in block)
        out.append(fence + "```")
        out.append("")
        i = j
    return out


def _in_list(lines: list[str]) -> bool:
    """Whether the paragraph that ends ``lines`` is a list item's."""
    for line in reversed(lines):
        if not line.strip():
            return False
        if re.match(r"^\s*(?:[*-]|\d+[.)])\s", line):
            return True
    return False


class RestDocstrings(griffe.Extension):
    """Griffe extension: every docstring of a loaded package through :func:`to_markdown`.

    An attribute documented Sphinx's way, by ``#:`` comment lines just above it, gets
    those lines as its docstring (griffe reads only a string after the assignment).
    """

    def on_package(self, *, pkg: griffe.Module, **kwargs) -> None:
        for obj in _walk(pkg):
            if obj.docstring is None and obj.is_attribute:
                _comment_docstring(obj)
            if obj.docstring is not None:
                obj.docstring.value = to_markdown(obj.docstring.value, _resolver(obj))


def _comment_docstring(attribute: griffe.Attribute) -> None:
    lines, index, comment = attribute.module.lines, (attribute.lineno or 0) - 2, []
    while 0 <= index < len(lines) and lines[index].strip().startswith("#:"):
        comment.insert(0, lines[index].strip()[2:].strip())
        index -= 1
    if comment:
        attribute.docstring = griffe.Docstring("\n".join(comment), lineno=index + 2,
                                               parent=attribute)


def _walk(obj: griffe.Object):
    yield obj
    for member in obj.members.values():
        if not member.is_alias:
            yield from _walk(member)


def _resolver(obj: griffe.Object) -> Callable[[str], str]:
    def resolve(target: str) -> str:
        head, _, rest = target.partition(".")
        try:
            full = obj.resolve(head)
        except (griffe.NameResolutionError, ValueError):
            return target
        return f"{full}.{rest}" if rest else full

    return resolve
