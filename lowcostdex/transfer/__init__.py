"""The transfer loop (issue 14): does a policy trained in simulation work on the robot?

``lowcostdex transfer --out DIR`` runs it on the user's robot (``--port``) or on emulated hidden
robots (``lowcostdex.hardware.emulated.hidden_robots``): record identification logs on the
robot, ``gap analyze`` them, train the same learner under each condition (nominal sim, the
project's domain randomization, the identified model, the identified model with narrow
randomization, the robot itself), evaluate every policy on every robot and write the table.

- ``loop``: the stages, resumable piece by piece inside one ``--out`` folder;
- ``conditions``: one finger's identification, and each simulated condition's model;
- ``config``, ``robots``, ``tables``: sizes and tasks, the robots, the tables and figure;
- ``cli``: the command;
- ``tilt``, ``tilt_joint``: a finger base's mounting tilt as a model edit, fitted from a
  valve-turning log (alone, or jointly with the other parameters the log sees, with profile
  intervals).

An application on top of the library: no library module imports it (an import-linter contract).
"""
