"""``lowcostdex main``: the whole story in one command, on the emulated D'Claw by default.

1. bus: an emulated D'Claw comes up on a Dynamixel bus (the real dynamixel_sdk code path): scanned
   (ids, models, firmware, temperatures, errors) and calibrated against the default map;
2. demos: the virtual teacher records kinesthetic demonstrations, auto-reset between episodes;
3. gap: an identification recording from the robot is compared with the nominal simulation; the
   gap analysis names what differs (the emulated robot carries servo effects the nominal sim
   lacks: ``robot_effects``), extends the model and measures the held-out gain;
4. train: DAPG from those demonstrations in simulation (MuJoCo with domain randomization over
   the effect catalogue: ``Budget.dapg_sim``), starting from the best of several behaviour
   clones on that simulation's validation episodes (``main_job.clones``), its iterates
   validated in the simulation the gap stage identified (``main_job.gapsim``; in the training
   simulation when the gap stage has not run), and NPG from scratch for comparison on the robot
   with its thermal guard and auto-resets active; the random actions, the clone, DAPG and NPG
   judged on the same held-out episodes of the robot (the run's policy is its best validated
   one); on the flip the DAPG policy's rollout is plotted (block orientation over time);
5. report: ``report.md`` (and ``report.html``) with the PNG plots, in one output folder.

``--port /dev/ttyUSB0`` runs the same stages on a real D'Claw (kinesthetic demos then need a
person); ``--task`` picks the task (``valve-target``, the default: turn the valve from 0 to a random target
180 +- 29 deg away; ``valve``: turn it 180 deg; ``valve-random``: random start and target;
``flip``: flip the block 180 deg about a horizontal axis); ``--size`` picks the budget: ``smoke`` (a check of every stage: about 4 minutes
of CPU, most of it the gap stage), ``default`` (about 25 minutes of CPU, 100 held-out robot
episodes per policy) or ``long``.
"""

from lowcostdex.main_job.job import (
    COMMAND,
    DEPENDS,
    OUTPUTS,
    RESULTS,
    STAGES,
    add_commands,
    open_job,
    run,
)
from lowcostdex.main_job.report import markdown_report, stage_summary, write_html
from lowcostdex.main_job.setup import (
    BUDGETS,
    ENV_ID,
    GAP_JOINTS,
    GAP_RATE,
    SIZES,
    TASKS,
    Budget,
    Context,
    TaskSetup,
    robot_effects,
)
from lowcostdex.main_job.stages import (
    robot_health_figure,
    stage_bus,
    stage_demos,
    stage_gap,
    stage_report,
    stage_train,
)

__all__ = [
    "BUDGETS", "COMMAND", "DEPENDS", "ENV_ID", "GAP_JOINTS", "GAP_RATE", "OUTPUTS", "RESULTS",
    "SIZES", "STAGES", "TASKS", "Budget", "Context", "TaskSetup", "add_commands",
    "markdown_report", "open_job", "robot_effects", "robot_health_figure", "run",
    "stage_bus", "stage_demos", "stage_gap", "stage_report", "stage_summary", "stage_train",
    "write_html",
]
