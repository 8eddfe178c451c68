"""Learning algorithms: policies, NPG, DAPG, BC, samplers, experiments, local models.

One algorithm per module, with the small pure functions underneath that tests call directly:

- ``configs``     the dataclass configs of policy, baseline, NPG, DAPG, BC and a run (no torch)
- ``policy``      Gaussian MLP policy (mjrl-style init), observation normalisation, numpy snapshot
- ``baseline``    value MLP V(s, t) with time features, fitted after each update
- ``returns``     discounted returns, GAE, whitening
- ``npg``         natural policy gradient: CG, Fisher-vector product, normalised step, KL check
- ``bc``          behaviour cloning (sets normalisation, output scaling, initial noise)
- ``dapg``        demo-augmented policy gradient (paper and mjrl demo weights)
- ``demos``       demonstration files and teacher recordings
- ``samplers``    serial, process-pool, vector-env and Ray samplers, seeded per trajectory
- ``experiment``  run directories: config, metrics, safe checkpoints, resume, learning curves
- ``train``       NPG/DAPG training runs
- ``train_cli``   ``lowcostdex train npg|dapg`` (arguments built without importing torch)
- ``cli``         the ``lowcostdex train`` command group
- ``local_models`` time-varying linear-Gaussian models and KL-constrained iLQG
"""
