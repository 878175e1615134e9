"""MkDocs hooks (``hooks:`` in ``mkdocs.yml``): the generated pages and their place in the nav.

* ``on_config``: the nav entry ``env/index.md`` becomes a section listing one page
  per id of :data:`auv_envs.ENVIRONMENTS`, so a new environment appears without
  editing ``mkdocs.yml``.
* ``on_files``: those pages (:mod:`env_pages`, written from the code's declarations),
  the agents overview (:mod:`agent_pages`, from the agent registry) and the
  repository's ``CHANGELOG.md`` join the site as generated files.
* ``on_page_markdown``: a relative link from a report to a file of the repository
  outside ``docs/`` (a script, a module) is kept as its path in code, since the site
  does not carry the source; a link to a file that does not exist is left for MkDocs
  to report.
"""

from __future__ import annotations

import re
from pathlib import Path

import agent_pages
import env_pages
from mkdocs.structure.files import File

import auv_envs

REPO = Path(__file__).resolve().parent.parent
LINK = re.compile(r"\[([^\]\n]+)\]\(([^)\s#]+)(#[^)\s]*)?\)")


def on_config(config):
    index = f"{env_pages.FOLDER}/index.md"
    section = [index] + [{env_id.split("/")[-1]: env_pages.page_path(env_id)}
                         for env_id in auv_envs.ENVIRONMENTS]
    if not _expand(config["nav"], index, section):
        raise ValueError(f"mkdocs.yml: the nav has no entry {index!r} to list the environments")
    return config


def _expand(nav: list, index: str, section: list) -> bool:
    for item in nav:
        if isinstance(item, dict):
            for title, value in item.items():
                if value == index:
                    item[title] = section
                    return True
                if isinstance(value, list) and _expand(value, index, section):
                    return True
    return False


def on_files(files, config):
    for path, markdown in env_pages.pages().items():
        files.append(File.generated(config, path, content=markdown))
    files.append(File.generated(config, "agents/index.md", content=agent_pages.page()))
    files.append(File.generated(config, "changelog.md", abs_src_path=str(REPO / "CHANGELOG.md")))
    return files


def on_page_markdown(markdown, page, config, files):
    docs = Path(config["docs_dir"]).resolve()
    here = (docs / page.file.src_uri).parent

    def relink(match: re.Match) -> str:
        text, target = match.group(1), match.group(2)
        if "://" in target or target.startswith(("/", "mailto:")):
            return match.group(0)
        path = (here / target).resolve()
        if path.is_relative_to(docs) or not path.is_relative_to(REPO) or not path.exists():
            return match.group(0)
        shown = f"`{path.relative_to(REPO).as_posix()}`"
        return shown if text.startswith("`") else f"{text} ({shown})"

    return LINK.sub(relink, markdown)
