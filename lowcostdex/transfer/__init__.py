"""The transfer loop (issue 14): does a policy trained in simulation work on the robot?

``lowcostdex transfer --out DIR`` runs it on the user's robot (``--port``) or on emulated hidden
robots (``lowcostdex.hardware.emulated.hidden_robots``): record identification logs on the
robot, ``gap analyze`` them, train the same learner under each condition (nominal sim, the
project's domain randomization, the identified model, the identified model with narrow
randomization, the robot itself), evaluate every policy on every robot and write the table.

- ``loop``: the stages, resumable piece by piece inside one ``--out`` folder;
- ``conditions``: one finger's identification, and each simulated condition's model;
- ``config``, ``robots``, ``tables``: sizes and tasks, the robots, the tables and figure;
- ``cli``: the command.

An application on top of the library: no library module imports it (an import-linter contract).
"""
