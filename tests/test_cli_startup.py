"""Start-up of the ``lowcostdex`` command: building its parser (``lowcostdex --help`` and every
subcommand do) must not import torch (~2.5 s); trainers import it in their handlers."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def _run(code: str) -> str:
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_building_the_parser_does_not_import_torch():
    loaded = _run(
        """
        import sys
        from lowcostdex.cli import build_parser

        build_parser().parse_args(["train", "npg", "--out", "run"])
        print(sorted(m for m in sys.modules if m == "torch" or m.startswith("torch.")))
        """
    )
    assert loaded == "[]"


def test_train_arguments_resolve_to_the_config_defaults_without_torch():
    result = _run(
        """
        import sys
        from lowcostdex.algos.configs import TrainConfig
        from lowcostdex.algos.train_cli import config_from_args
        from lowcostdex.cli import build_parser

        args = build_parser().parse_args(
            ["train", "dapg", "--demos", "d.h5", "--out", "run", "--n-iter", "3", "--lam0", "0.2"]
        )
        cfg = config_from_args(args)
        d = TrainConfig()
        assert (cfg.algo, cfg.n_iter, cfg.dapg.lam0) == ("dapg", 3, 0.2), cfg
        assert (cfg.npg, cfg.policy, cfg.bc, cfg.n_traj) == (d.npg, d.policy, d.bc, d.n_traj)
        print("torch" in sys.modules)
        """
    )
    assert result == "False"
