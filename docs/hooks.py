"""MkDocs hook: the tutorials live in ``notebooks/``, beside the code they test.

This adds each ``notebooks/*.ipynb`` to the site (as ``notebooks/<name>.ipynb``, outside
``docs_dir``) before ``mkdocs-jupyter`` turns notebooks into pages (it executes them at build time:
``execute: true`` in ``mkdocs.yml``).
"""

from __future__ import annotations

from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

REPO = Path(__file__).resolve().parents[1]


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
