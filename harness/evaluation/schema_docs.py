"""The schema as documentation: the rows of ``docs/evaluation.md``'s schema table generated from the
declarations they describe (the scene's spec types and the engine's settings sections)."""

from __future__ import annotations

import dataclasses
from functools import lru_cache
from typing import Any

from harness.engine.config import TrackerConfig
from harness.evaluation.scenario import PER_RUN, field_default
from harness.scene.spec import CameraSpec, MarkerSpec, ObservationSpec, OccluderGeom, OccluderSpec, SubjectSpec
from harness.settings import section_types, values_text

_PER_RUN_TEXT = {(MarkerSpec, "seed"): "none: drawn per run", (OccluderSpec, "seed"): "none: drawn per run",
                 (SubjectSpec, "seed"): "none: drawn per run", (CameraSpec, "azimuth"): "or `random`: drawn per run"}


def _default_text(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return "[" + ", ".join(_default_text(v) for v in value) + "]"
    if isinstance(value, str):
        return f"`{value}`"
    return repr(value) if not isinstance(value, float) else f"{value:g}"


@lru_cache(maxsize=1)
def schema_markdown() -> str:
    """The generated rows of the schema table for the sections that come from the spec types and the engine's
    settings sections (``| key | default | unit | values | meaning |``); ``docs/evaluation.md`` holds them
    verbatim (tested)."""
    lines = ["| key | default | unit | values | meaning |", "|---|---|---|---|---|"]
    for section, spec_cls in (("subject", SubjectSpec), ("markers", MarkerSpec), ("camera", CameraSpec),
                              ("occluders", OccluderSpec), ("occluders.geoms[]", OccluderGeom),
                              ("observation", ObservationSpec)):
        for f in dataclasses.fields(spec_cls):
            meta = f.metadata
            values = meta.get("values", "")
            if (spec_cls, f.name) in _PER_RUN_TEXT:
                values += f"; {_PER_RUN_TEXT[(spec_cls, f.name)]}"
                default = _default_text(PER_RUN[(spec_cls, f.name)][1])
            else:
                default = _default_text(field_default(f))
            lines.append(f"| `{section}.{f.name}` | {default} | {meta.get('unit', '')} | {values} | "
                         f"{meta.get('meaning', '')} |")
    for section, kind in section_types(TrackerConfig).items():
        for f in dataclasses.fields(kind):
            meta = f.metadata
            lines.append(f"| `engine.{section}.{f.name}` | {_default_text(f.default)} | {meta['unit']} | "
                         f"{values_text(kind, f)} | {meta['meaning']} |")
    return "\n".join(lines) + "\n"
