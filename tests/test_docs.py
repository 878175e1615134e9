"""The documentation site builds with every warning an error, and says what the code says.

``mkdocs build --strict`` fails on a broken link, a page left out of the nav or a
docstring that does not parse. The environment pages are written from the classes
when the site is built (``docs/env_pages.py``), so each must show its environment's
reward terms and observation modes; the agents page is written from the registry.
"""

from __future__ import annotations

import importlib.util
import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import auv_envs

pytest.importorskip("mkdocs")
pytest.importorskip("material")
pytest.importorskip("mkdocstrings_handlers.python")

REPO = Path(__file__).resolve().parent.parent


def _docs_module(name: str):
    """A helper module of the site's build, from ``docs/`` (not a package)."""
    spec = importlib.util.spec_from_file_location(name, REPO / "docs" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


rest_markdown = _docs_module("rest_markdown")


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert result.returncode == 0, f"mkdocs build --strict failed:\n{result.stderr[-4000:]}"
    return out


@pytest.mark.parametrize("env_id", tuple(auv_envs.ENVIRONMENTS))
def test_every_environment_has_a_page_from_its_declarations(site, env_id):
    cls = auv_envs.task_class(env_id)
    page = site / "env" / env_id.split("/")[-1] / "index.html"
    assert page.is_file(), f"no page for {env_id}"
    html = page.read_text()
    for term in cls.reward_terms:
        assert f"<code>reward_{term}</code>" in html, f"{env_id}: reward term {term} missing"
    for mode in cls.obs_modes:
        assert f"<code>{mode}</code>" in html, f"{env_id}: obs mode {mode} missing"
    for level in cls.difficulty_presets:
        assert f"<code>{level}</code>" in html
    assert env_id in (site / "env" / "index.html").read_text()


def test_agents_page_lists_every_builtin_agent(site):
    # The catalogue's and the shipped policies' agents: what the build's registry holds
    # (this process's may hold test agents too).
    from baselines.catalogue import builtin_specs

    html = (site / "agents" / "index.html").read_text()
    for spec in builtin_specs():
        assert f"<code>{spec.group or spec.name}</code>" in html, f"agent {spec.name} missing"


def test_rest_simple_table_becomes_a_markdown_table():
    text = """Rewards:

    ======  ==============
    term    value
    ======  ==============
    ``a``   -0.001 |a|^2
    ``b``   +10 on
            docking
    ======  ==============
    """
    lines = [line for line in rest_markdown.to_markdown(text).splitlines() if line.strip()]
    assert lines[1:] == ["    | term | value |", "    |---|---|",
                         r"    | `a` | -0.001 \|a\|^2 |", "    | `b` | +10 on docking |"]


def test_rest_roles_and_literal_blocks():
    text = "See :class:`~pkg.mod.Thing` and :func:`helper`::\n\n    x = 1\n\nafter"
    known = {"helper": "pkg.mod.helper"}
    out = rest_markdown.to_markdown(text, resolve=lambda name: known.get(name, name))
    assert ('<autoref identifier="pkg.mod.Thing" optional><code>Thing</code></autoref>'
            in out)
    assert '<autoref identifier="pkg.mod.helper" optional><code>helper</code></autoref>:' in out
    assert "```text\nx = 1\n```" in out


def test_every_environment_has_its_own_summary_and_a_picture(site):
    index = (site / "env" / "index.html").read_text()
    summaries = set()
    for env_id in auv_envs.ENVIRONMENTS:
        name = env_id.split("/")[-1]
        page = (site / "env" / name / "index.html").read_text()
        assert "<img" in page, f"{env_id}: no picture on its page"
        summaries.add(inspect.cleandoc(auv_envs.task_class(env_id).__doc__).split("\n\n")[0])
    assert len(summaries) == len(auv_envs.ENVIRONMENTS)  # no two share a summary
    assert index.count("<img") == len(auv_envs.ENVIRONMENTS)


#: Internal work-item numbers (the word "stop" or "issue" and a number) that no reader
#: can follow.
INTERNAL_NUMBER = re.compile(r"\bstop [0-9]+|\bissues? #?[0-9]+", re.IGNORECASE)


def test_no_page_or_code_speaks_of_internal_work_items():
    tracked = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True,
                             check=True).stdout.split()
    found = []
    for name in tracked:
        path = REPO / name
        if path.suffix not in {".md", ".py", ".yml", ".yaml", ".toml", ".cfg", ".txt", ""} \
                or not path.is_file() or name == "tests/test_docs.py":
            continue
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if INTERNAL_NUMBER.search(line):
                found.append(f"{name}:{number}: {line.strip()}")
    assert not found, "\n".join(found)
