"""The manifest's ``symmetries`` section: written by the rule's command, read by :mod:`helpers.data.manifest`.

The section is the last block of ``data_manifest.yaml``, after its marker comment; writing replaces that
block (or appends it) and leaves every other line of the file as it was.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import yaml

from ...core.fileio import atomic_write_text
from .rule import RULE_VERSION, SymmetryRule

#: First line of the section's block: everything from it to the end of the file is the section.
MARKER = "# Visual symmetries, declared by a rule from the meshes and renders alone"


def write_section(manifest_path: Path, objects: dict[str, dict], rule: SymmetryRule) -> Path:
    """Replace (or append) the section with ``objects`` (name -> :func:`.rule.manifest_block`), merged over the
    objects already declared there by the same rule version."""
    text = manifest_path.read_text()
    head, _, old = text.partition(MARKER)
    record = {"module": "helpers.data.symmetry", "version": RULE_VERSION, **asdict(rule)}
    previous = {}
    if old:  # keep the objects not re-run now, if the same rule (version and settings) declared them
        sec = (yaml.safe_load(MARKER + old) or {}).get("symmetries", {}) or {}
        if sec.get("rule") == record:
            previous = sec.get("objects", {}) or {}
    merged = {**previous, **objects}
    body = {"symmetries": {"rule": record,
                           "objects": {k: merged[k] for k in sorted(merged)}}}
    block = (MARKER + " (helpers.data.symmetry; never from a method's\n"
             "# accuracy). Each object: discrete rotations (3x3 row-major, model frame: R_m2c @ S looks like R_m2c),\n"
             "# continuous axes, and the evidence: every surface candidate with its surface distance / that of a small\n"
             "# turn, and the share of query-like views in which the render at R @ S is closer to R than a small turn\n"
             "# is, in the network's input space. Regenerate: python -m helpers.data.symmetry --write\n")
    out = head.rstrip("\n") + "\n\n" + block + yaml.safe_dump(body, sort_keys=False, width=120, default_flow_style=None)
    return atomic_write_text(manifest_path, out)

