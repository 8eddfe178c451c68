"""Learned local models: TVLG dynamics with a GMM prior and KL-constrained iLQG.

Modules, one algorithm each: :mod:`.costs` (quadratic costs and ramps), :mod:`.controller` (TVLG
controllers, PD initialisation, exploration noise), :mod:`.gmm` (EM mixture and NIW prior),
:mod:`.dynamics` (per-step fit), :mod:`.lqr` (backward/forward pass, KL, expected cost),
:mod:`.traj_opt` (eta search, step rule), :mod:`.tvlg` (one iteration), :mod:`.train`
(rollouts on the gymnasium envs, run directory, CLI) and :mod:`.mdgps` (mirror-descent guided
policy search: one controller per start condition distilled into one neural policy).
"""
