"""`plchmi export`: the controlled cell (its control law and safety layer) as IEC 61131-3
code for a real PLC.

One PLC model (:mod:`hmi.export.model`, built by :mod:`hmi.export.build`), one writer per
target: Structured Text (:mod:`hmi.export.st`) and PLCopen TC6 XML
(:mod:`hmi.export.plcopen`). docs/plc-export.md says what is exported and how to run it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hmi.export.build import build
from hmi.export.model import PlcProject
from hmi.outpaths import check_outputs
from hmi.project.model import Project

FORMATS = ("st", "plcopen")


@dataclass(frozen=True)
class Written:
    path: Path
    model: PlcProject


def render(model: PlcProject, fmt: str) -> tuple[str, str]:
    """(file name, text) of the model in one format."""
    if fmt == "st":
        from hmi.export.st import write_st
        return f"{model.name}.st", write_st(model)
    if fmt == "plcopen":
        from hmi.export.plcopen import write_plcopen
        return f"{model.name}.xml", write_plcopen(model)
    raise ValueError(f"unknown format {fmt!r}")


def export(project: Project, fmt: str, out_dir: Path, control: str | None = None) -> Written:
    """Build the model (the control law `control`, else the project's default one) and
    write it to `out_dir` (created if needed)."""
    model = build(project, control)
    filename, text = render(model, fmt)
    path = out_dir / filename
    # never over a file the project was read from (-o the project's folder, a name alike)
    check_outputs([(f"-o {out_dir}:", "the export", path)],
                  [("a file of the project", Path(name)) for name in project.files])
    out_dir.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return Written(path, model)
