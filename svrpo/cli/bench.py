"""`svrpo bench`: everything after `bench` goes to svrpo.tools.bench."""

from __future__ import annotations

import argparse


def run(args: argparse.Namespace, extra: list[str]) -> int:
    from svrpo.tools import bench

    return bench.main(extra)
