"""How far each inner step's gradient is from the true gradient, split into the batch's sampling
error and the inner loop's own noise; and the gradient noise scale B_simple at a policy.

At a policy w~ (a checkpoint), the tool draws a large reference batch of M steps and an ordinary
batch of N steps with pi_{w~}, both prepared as training prepares a batch (GAE with the run's
baseline, advantages standardised over the batch, the run's observation normaliser). It then
replays one outer iteration of an estimator's inner loop on the ordinary batch with the library's
own loop (svrpo.algorithm.update.update_policy, observed through UpdateParts.observe_step) and, at
every inner step j, compares three vectors at the iterate w_j:

* g_j    the step's gradient estimate (what the estimator returned);
* gb_j   grad U_N(w_j), the surrogate's gradient on all N rows of the ordinary batch (TRPO's
         gradient at w_j; for a fresh-sample estimator: what the snapshot batch alone gives);
* G_j    grad U_M(w_j) on the reference batch: the true gradient of the expected surrogate around
         w~ (steps drawn with pi_{w~}), up to the reference's own error, which is reported.

Then ||g - G||^2 = ||g - gb||^2 + ||gb - G||^2 + 2 <g - gb, gb - G> exactly: the total error is the
inner loop's noise (what variance reduction removes) plus the batch's sampling error (what no
re-use of the batch can remove) plus their cross term. The same split is recorded for the search
directions F^-1 g, F^-1 gb, F^-1 G, all solved with the step's own Fisher product and metric.

The reference batch is cut into K contiguous parts (the sampler lays rows out env by env, in time
order, so a part holds whole stretches of episodes). The spread of the K part gradients gives the
reference's standard error and the per-sample covariance: steps of one episode are correlated, so
tr(Sigma) is estimated from part means, tr(Sigma) = n Var_k(g_k) summed over coordinates (n rows a
part), which is the long-run covariance that decides Var(mean of N rows) = tr(Sigma) / N when a
part is much longer than the correlation time (a few episodes). B_simple = tr(Sigma) / |G|^2
(McCandlish, Kaplan, Amodei et al. 2018, "An Empirical Model of Large-Batch Training", Eq. 2.8),
with |G|^2 estimated without bias as ||G_M||^2 - tr(Sigma) / M.

Standardising the reference's advantages over all M rows is the large-N limit of the per-batch
standardisation training uses; the difference is O(1/N) in the gradient.
"""

from __future__ import annotations

import copy
import csv
import io
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from svrpo.algorithm.objectives import SurrogateBatch, surrogate
from svrpo.algorithm.parts import UpdateParts
from svrpo.algorithm.step_rows import DrawWithIterate
from svrpo.algorithm.trust_region.metrics import MatVec
from svrpo.algorithm.update import update_policy
from svrpo.analysis.gradient_split import (
    ErrorSplit,
    NoiseScale,
    error_split,
    gradient_noise_scale,
    reference_gradient,
    vector_error,
)
from svrpo.config import Config
from svrpo.errors import CheckpointError, ConfigError
from svrpo.models.parameters import flat_gradient, flat_parameters
from svrpo.models.policy import MlpPolicy

if TYPE_CHECKING:
    from svrpo.algorithm.run import Run
    from svrpo.sampling.sampler import Batch

__all__ = ["GradientErrorReport", "StepErrors", "measure_gradient_error", "replay_errors"]


@dataclass(frozen=True)
class StepErrors:
    """One inner step j of one estimator: its gradient and its direction against gb_j and G_j."""

    estimator: str
    step: int
    """j (0-based; a step skipped for a non-finite gradient has no row)."""
    gradient: ErrorSplit
    direction: ErrorSplit
    """s_j against F^-1 gb_j and F^-1 G_j (the step's metric and Fisher product)."""
    reference_standard_error: float
    """ReferenceGradient.standard_error of G_j: ||G_j - G||^2 adds about its square to total."""
    point: torch.Tensor = field(repr=False, compare=False)
    """(P,) w_j (not written to steps.csv)."""
    estimate: torch.Tensor = field(repr=False, compare=False)
    """(P,) g_j (not written to steps.csv)."""

    def row(self) -> dict[str, Any]:
        """One flat CSV row: gradient_total_squared, ..., direction_cross_term."""
        out: dict[str, Any] = {"estimator": self.estimator, "step": self.step}
        for name, split in (("gradient", self.gradient), ("direction", self.direction)):
            for part in ("total", "noise", "sampling"):
                for key, value in asdict(getattr(split, part)).items():
                    out[f"{name}_{part}_{key}"] = value
            out[f"{name}_cross_term"] = split.cross_term
        out["reference_standard_error"] = self.reference_standard_error
        return out


def replay_errors(
    name: str,
    policy: MlpPolicy,
    batch: SurrogateBatch,
    reference: SurrogateBatch,
    reference_parts: int,
    parts: UpdateParts,
    generator: torch.Generator,
    draw_fresh: DrawWithIterate | None = None,
) -> list[StepErrors]:
    """Run one outer iteration of `parts`' inner loop on `batch` (in place on `policy`, which is w~
    on entry) with the library's loop, and return each step's errors.

    A fresh-sample estimator (svrpo/algorithm/fresh/) needs `draw_fresh` (update_policy's `draw`).
    `generator` draws the mini-batches and Fisher subsets.
    """
    kind = parts.loop.surrogate
    records: list[StepErrors] = []

    def observe(step: int, gradient: torch.Tensor, direction: torch.Tensor,
                fisher_product: MatVec) -> None:
        true = reference_gradient(policy, reference, reference_parts, kind)
        batch_gradient = flat_gradient(surrogate(policy, batch, kind), policy)
        true_direction = parts.metric.direction(true.mean, fisher_product)[0]
        batch_direction = parts.metric.direction(batch_gradient, fisher_product)[0]
        records.append(StepErrors(name, step, error_split(gradient, batch_gradient, true.mean),
                                  error_split(direction, batch_direction, true_direction),
                                  true.standard_error, flat_parameters(policy), gradient.detach().clone()))

    observed = replace(parts, observe_step=observe)
    update_policy(policy, batch, observed, generator, torch.Generator().manual_seed(0), draw=draw_fresh)
    return records


@dataclass(frozen=True)
class GradientErrorReport:
    """What measure_gradient_error found at one policy (and wrote, when given a directory)."""

    source: str
    """The checkpoint read (or 'initial policy of CONFIG' with initial=True)."""
    env_id: str
    iteration: int
    env_steps: int
    batch_size: int
    """N: rows of the ordinary batch."""
    reference_steps: int
    reference_parts: int
    seed: int
    noise_scale: NoiseScale
    """At w~ (from the reference batch)."""
    batch_sampling_error: float
    """||gb - G||^2 at w~ (j = 0), to set against noise_scale.expected_sampling_error(N)."""
    steps: list[StepErrors] = field(default_factory=list)
    cpu_seconds: float = 0.0
    """CPU seconds of this process (sampling workers excluded) for the whole measurement."""

    def summary(self) -> dict[str, Any]:
        """summary.json: everything but the per-step rows."""
        out = {key: getattr(self, key) for key in self.__dataclass_fields__ if key != "steps"}
        out["noise_scale"] = asdict(self.noise_scale)
        out["expected_sampling_error"] = self.noise_scale.expected_sampling_error(self.batch_size)
        out["estimators"] = list(dict.fromkeys(record.estimator for record in self.steps))  # in replay order
        return out


def _load_state(path: Path) -> tuple[dict[str, Any], Path]:
    from svrpo.analysis.evaluation import find_checkpoint
    from svrpo.rundir import checkpoint

    source = find_checkpoint(path)  # EvaluationError (one line) for a missing path or no checkpoint
    return checkpoint.load(source), source


def replay_configs(saved: Config, estimators: Sequence[str], update_from: Sequence[str | os.PathLike[str]],
                   overrides: Mapping[str, Any], seed: int) -> dict[str, Config]:
    """label -> the config of each replay (ConfigError, one line, for any that is invalid).

    A name in `estimators`: the checkpoint's config with that estimator (J = 1 for `full`, as
    TRPO). A run directory (or its config.json) in `update_from`: that run's whole config, e.g. an
    estimator's confirmed run, labelled by its experiment (run.json) or directory name; its
    network and baseline must be the checkpoint's. `overrides` and `seed` apply to every replay.
    """
    from svrpo.algorithm.run import MUST_MATCH

    changes = {**dict(overrides), "seed": seed}
    configs: dict[str, Config] = {}
    for name in estimators:
        configs[name] = saved.replace(**{"estimator": name, **changes,
                                         **({"inner_steps": 1} if name == "full" else {})})
    for entry in update_from:
        path = Path(entry)
        file = path / "config.json" if path.is_dir() else path
        try:
            other = Config.from_json(file.read_text())
        except (OSError, ValueError, TypeError) as error:
            raise ConfigError(f"--update-from {path}: no readable config.json ({error})") from None
        shapes = [name for name in MUST_MATCH if name not in ("num_workers", "envs_per_worker")
                  and getattr(other, name) != getattr(saved, name)]
        if shapes:
            raise ConfigError(f"--update-from {path} differs from the checkpoint in {', '.join(shapes)}")
        label: str = other.estimator
        record = file.parent / "run.json"
        if record.is_file():
            label = str(json.loads(record.read_text()).get("experiment") or file.parent.parent.name)
        configs[label if label not in configs else f"{label}:{file.parent.name}"] = other.replace(**changes)
    if not configs:
        raise ConfigError("give at least one --estimator or --update-from")
    return configs


def sample_frozen(run: Run, num_steps: int) -> Batch:
    """num_steps steps with the current policy, rewards scaled as in training (iteration.sample:
    normalize_rewards), but from the checkpoint's reward statistics every time: the measurement
    must not let a large reference batch move the scale the ordinary batch is read in."""
    from svrpo.algorithm.iteration import sample

    saved = copy.deepcopy(run.reward_normalizer)
    batch = sample(run, num_steps)
    run.reward_normalizer = saved
    return batch


def measure_gradient_error(
    path: str | os.PathLike[str],
    estimators: Sequence[str] = (),
    reference_steps: int = 200_000,
    reference_parts: int = 40,
    seed: int = 0,
    overrides: Mapping[str, Any] | None = None,
    initial: bool = False,
    out: str | os.PathLike[str] | None = None,
    update_from: Sequence[str | os.PathLike[str]] = (),
) -> GradientErrorReport:
    """The gradient errors of `estimators` at the policy of a run directory's latest checkpoint
    (or a checkpoint file), and B_simple there; see the module docstring.

    `estimators` and `update_from`: what to replay (see replay_configs); all of them with one N
    (batch_size). `overrides`: config fields set for every replay (e.g. inner_steps,
    minibatch_size, max_kl, batch_size = N); the policy, baseline and normaliser come from the
    checkpoint whatever they say. The reference and the ordinary batch are drawn once, with the
    first replay's sampler settings. `initial`: the untrained policy, baseline and normaliser that
    the checkpoint's config starts from (iteration 0) in place of the checkpoint's. `seed`: the
    sampler's and the mini-batch streams' seed (the same seed draws the same reference and
    batch, so separate calls are paired). `out`: a directory to write steps.csv, summary.json and
    gradient_error.png into (atomically, at the end). ConfigError / CheckpointError /
    EvaluationError (one line) for bad input, before any sampling.
    """
    import time

    from svrpo.algorithm.iteration import advantage_scale, fresh_surrogate_batch, surrogate_batch
    from svrpo.algorithm.parts import update_parts
    from svrpo.algorithm.run import build_run
    from svrpo.algorithm.streams import RandomStreams

    if reference_parts < 2 or reference_steps < 2 * reference_parts:
        raise ConfigError(f"reference_parts must be >= 2 and reference_steps >= 2 * parts; got "
                          f"{reference_parts} parts of {reference_steps} steps")
    state, source = _load_state(Path(path))
    try:
        saved = Config.from_json(state["config"])
    except (ConfigError, ValueError, TypeError, KeyError) as error:
        raise CheckpointError(f"{source} holds no readable config: {error}") from None
    configs = replay_configs(saved, estimators, update_from, overrides or {}, seed)
    base = next(iter(configs.values()))
    sizes = {config.batch_size for config in configs.values()}
    if len(sizes) > 1:
        raise ConfigError(f"the replays have different batch sizes N ({sorted(sizes)}): give one "
                          "--batch_size, or measure them in separate calls with the same --seed")
    cpu_started = time.process_time()
    run = build_run(base)
    try:
        if initial:  # iteration 0 of the checkpoint's run: built from its own seed
            untrained = build_run(saved.replace(num_workers=0))
            untrained.sampler.close()
            state = untrained.learned_state()
        try:
            run.load_learned_state(state)
        except (KeyError, RuntimeError, ValueError, TypeError) as error:
            raise CheckpointError(f"{source} does not fit its own config: {error}") from None
        # The reference first: the ordinary batch then starts mid-episode, as in training.
        reference = surrogate_batch(run, sample_frozen(run, reference_steps)).data
        raw_batch = sample_frozen(run, base.batch_size)
        batch = surrogate_batch(run, raw_batch).data
        start = copy.deepcopy(run.policy.state_dict())
        at_start = reference_gradient(run.policy, reference, reference_parts, base.surrogate)
        sampling = vector_error(flat_gradient(surrogate(run.policy, batch, base.surrogate), run.policy),
                                at_start.mean).squared
        steps: list[StepErrors] = []
        for name, config in configs.items():
            run.policy.load_state_dict(start)
            streams = RandomStreams(seed)
            parts = update_parts(config, streams=streams)
            draw_fresh = None
            if config.fresh_samples:
                sampling_policy, scale = copy.deepcopy(run.policy), advantage_scale(run, raw_batch)

                def draw_fresh(num_steps: int, sampling_policy: MlpPolicy = sampling_policy,
                               scale: tuple[torch.Tensor, torch.Tensor] = scale) -> SurrogateBatch:
                    drawn = sample_frozen(run, num_steps)
                    return fresh_surrogate_batch(run, drawn, scale, sampling_policy).data

            steps += replay_errors(name, run.policy, batch, reference, reference_parts, parts,
                                   streams.generator("minibatches"), draw_fresh)
    finally:
        run.sampler.close()
    report = GradientErrorReport(
        source=f"initial policy of {source}" if initial else str(source), env_id=base.env_id,
        iteration=0 if initial else int(state["iteration"]),
        env_steps=0 if initial else int(state["env_steps"]), batch_size=base.batch_size,
        reference_steps=reference_steps, reference_parts=reference_parts, seed=seed,
        noise_scale=gradient_noise_scale(at_start), batch_sampling_error=sampling, steps=steps,
        cpu_seconds=time.process_time() - cpu_started)
    if out is not None:
        write_report(report, Path(out))
    return report


def write_report(report: GradientErrorReport, out: Path) -> None:
    """steps.csv, summary.json and gradient_error.png in `out`, each written atomically."""
    from svrpo.rundir.atomic import replace_atomically, write_text_atomic

    rows = [record.row() for record in report.steps]
    text = io.StringIO()
    if rows:
        writer = csv.DictWriter(text, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    write_text_atomic(out / "steps.csv", text.getvalue())
    write_text_atomic(out / "summary.json", json.dumps(report.summary(), indent=2, default=_plain) + "\n")
    figure = plot_errors(report)
    replace_atomically(out / "gradient_error.png",
                       lambda handle: figure.savefig(handle, format="png", dpi=110))


def _plain(value: Any) -> Any:
    return float(value) if isinstance(value, float) else str(value)


def plot_errors(report: GradientErrorReport) -> Any:
    """Relative error vs inner step per estimator: against G (left), against gb (right); the
    batch's own sampling error ||gb - G|| / ||G|| as a dashed line on the left."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    by_name: dict[str, list[StepErrors]] = {}
    for record in report.steps:
        by_name.setdefault(record.estimator, []).append(record)
    for name, records in by_name.items():
        js = [r.step for r in records]
        line = left.plot(js, [r.gradient.total.relative for r in records], marker="o", label=name)[0]
        left.plot(js, [r.gradient.sampling.relative for r in records], ls="--", color=line.get_color())
        right.plot(js, [r.gradient.noise.relative for r in records], marker="o", label=name)
    left.set_title("||g_j - G_j|| / ||G_j|| (dashed: batch ||gb_j - G_j|| / ||G_j||)", fontsize=9)
    right.set_title("||g_j - gb_j|| / ||gb_j||: inner-loop noise", fontsize=9)
    for axis in (left, right):
        axis.set_xlabel("inner step j")
        axis.xaxis.set_major_locator(MaxNLocator(integer=True))
        axis.set_yscale("symlog", linthresh=1e-3)
        axis.grid(alpha=0.3)
    left.set_ylabel("relative error")
    right.legend(fontsize=8)
    scale = report.noise_scale
    figure.suptitle(f"{report.env_id}, iteration {report.iteration}: N = {report.batch_size}, "
                    f"B_simple = {scale.b_simple:.3g} (M = {scale.reference_rows})", fontsize=10)
    figure.tight_layout()
    return figure
