"""MkDocs hook: a stand-in for nav pages that another change adds, while they are missing.

Only the pages listed in ``PENDING`` get one, and the build log says so; any other
missing page still fails ``mkdocs build --strict``.
"""

from __future__ import annotations

import logging

from mkdocs.structure.files import File

log = logging.getLogger("mkdocs.hooks.placeholders")

#: page -> what it will hold
PENDING = {
    "nonreversible.md": (
        "Non-reversible test problems",
        "The long-time comparison of the feedback integrator with DLA, projected RK4, plain RK4 "
        "and LSODA on the non-reversible problems of Modin & Verdier (Numer. Math. 145 (2020)), "
        "with the drift of every first integral.",
    ),
    "rigid_body.md": (
        "The rigid body and the theory of gains",
        "the free rigid body on SO(3) as a scene, and how liefi's gain theory chooses the gains.",
    ),
}


def on_files(files, config):
    for page, (title, what) in PENDING.items():
        if files.get_file_from_path(page) is None:
            log.info("placeholders: %s is not written yet; building a stand-in page", page)
            text = f"# {title}\n\n!!! note \"Not written yet\"\n    This page will hold: {what}\n"
            files.append(File.generated(config, page, content=text))
    return files
