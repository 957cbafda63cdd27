"""`svrpo evaluate`: deterministic episodes (and a video) of a run's policy."""

from __future__ import annotations

import argparse
from pathlib import Path

from svrpo.cli.common import UsageError, check_writable


def run(args: argparse.Namespace, extra: list[str]) -> int:
    if extra:
        raise UsageError(f"unexpected arguments {' '.join(extra)}")
    from svrpo.analysis.evaluation import evaluate, record_video

    if args.episodes < 1:
        raise UsageError(f"--episodes must be >= 1; got {args.episodes}")
    width, _, height = args.video_size.partition("x")
    if not (width.isdigit() and height.isdigit()):
        raise UsageError(f"--video-size must be WIDTHxHEIGHT, e.g. 480x480; got {args.video_size!r}")
    if args.video:  # a video path that cannot be written fails now, not after the evaluation
        check_writable(Path(args.video), "--video")
    from svrpo.errors import EnvError
    from svrpo.sampling.envs import ImportNotAllowedError

    try:
        result = evaluate(Path(args.path), args.episodes, args.seed, args.allow_import)
    except ImportNotAllowedError as error:  # worded for the command line, not the Python API
        raise EnvError(error.worded(python=False)) from None
    policy = result.policy
    print(f"{policy.config.env_id}, iteration {policy.iteration} ({policy.env_steps} steps), "
          f"{policy.checkpoint}: return {result.mean:.2f} +- {result.std:.2f} (mean +- std over "
          f"{args.episodes} deterministic episode{'s' if args.episodes > 1 else ''}, seeds "
          f"{args.seed}..{args.seed + args.episodes - 1})")
    print("returns: " + " ".join(f"{value:.2f}" for value in result.returns))
    if args.video:
        video = record_video(Path(args.path), Path(args.video), args.video_episodes, args.seed,
                             (int(width), int(height)), args.allow_import)
        print(f"wrote {video.path}: {video.frames} frames at {video.fps:.1f} fps "
              f"({args.video_episodes} episode(s), MUJOCO_GL={video.backend})")
    return 0
