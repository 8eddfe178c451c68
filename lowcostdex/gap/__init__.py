"""Reality-gap analysis (issue 6): show what the simulation gets wrong, name the cause, extend
the model, measure the gain. Guide: docs/gap_analysis.md.

Python API, one function per step::

    ds = load_dataset(["a.csv", "b.csv"], model="robot.xml")   # or BAM JSON: bench auto-detected
    result = analyze(ds, GapConfig())                          # replay, diagnose, select, gain
    write_report(result, "report/")                            # report.json/.md, PNGs, extended/
    ext = load_extended("report/")                             # effects, MJCF, DR ranges
    plant = ext.plant(); dr = ext.domain_randomization()
"""

from lowcostdex.gap.analyze import GapConfig, GapResult, analyze
from lowcostdex.gap.dataset import Dataset, load_dataset
from lowcostdex.gap.extension import ExtendedModel, load_extended, save_extended
from lowcostdex.gap.logs import LogError, Trajectory, read_log, write_log, zoh
from lowcostdex.gap.replay import Replayer
from lowcostdex.gap.report import write_report

__all__ = [
    "Dataset", "ExtendedModel", "GapConfig", "GapResult", "LogError", "Replayer", "Trajectory",
    "analyze", "load_dataset", "load_extended", "read_log", "save_extended",
    "write_log", "write_report", "zoh",
]
