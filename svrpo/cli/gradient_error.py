"""`svrpo gradient-error`: the inner steps' gradient errors at a run's checkpoint."""

from __future__ import annotations

import argparse
from pathlib import Path

from svrpo.cli.common import UsageError, parse_overrides
from svrpo.config import coerce_field


def run(args: argparse.Namespace, extra: list[str]) -> int:
    from svrpo.analysis.gradient_error import measure_gradient_error

    names = [name for text in args.estimator for name in text.split(",") if name]
    if len(set(names)) != len(names):
        raise UsageError(f"--estimator names an estimator twice: {','.join(names)}")
    overrides = {name: coerce_field(name, value) for name, value in parse_overrides(extra).items()}
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file; give a directory")
    report = measure_gradient_error(Path(args.path), names, args.reference_steps, args.parts,
                                    args.seed, overrides, args.initial, out, args.update_from)
    scale = report.noise_scale
    print(f"{report.env_id}, iteration {report.iteration} ({report.env_steps} steps), {report.source}")
    print(f"B_simple = {scale.b_simple:.4g} (tr Sigma = {scale.trace_covariance:.4g}, |G|^2 = "
          f"{scale.gradient_norm_sq:.4g}, M = {scale.reference_rows}); N = {report.batch_size}: "
          f"||gb - G||^2 = {report.batch_sampling_error:.4g} (expected tr Sigma / N = "
          f"{scale.expected_sampling_error(report.batch_size):.4g})")
    for record in report.steps:
        g = record.gradient
        print(f"{record.estimator:>10} j={record.step:<3} |g-G|^2 {g.total.squared:.4g} = "
              f"|g-gb|^2 {g.noise.squared:.4g} + |gb-G|^2 {g.sampling.squared:.4g} + cross "
              f"{g.cross_term:.4g}; cos(g, G) {g.total.cosine:.3f}, cos(s, F^-1 G) "
              f"{record.direction.total.cosine:.3f}")
    print(f"wrote {out / 'steps.csv'}, {out / 'summary.json'}, {out / 'gradient_error.png'} "
          f"({report.cpu_seconds:.1f} CPU s in this process)")
    return 0
