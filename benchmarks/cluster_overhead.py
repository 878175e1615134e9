"""Wall time of one small board on the local backend and on a two-node Ray cluster.

Both evaluate the same episodes in the same run, alternately (this machine is
shared and noisy, so their ratio means more than either time): the local
backend with as many worker processes as the cluster has CPUs, and the Ray
backend on a :class:`~baselines.evaluation.LocalRayCluster` of two nodes on
this machine (``ray start``, a temporary directory each), whose start is not
counted. The Ray time includes what every evaluation on a cluster pays:
connecting, packing and sending the source tree (``runtime_env``), starting
the workers and bringing the rows back. No cache; ``--clips`` records the
first seed's episode of every pair, whose files come back to the driver too.

    python benchmarks/cluster_overhead.py [--seeds N] [--repeats R] [--cpus-per-node C] [--clips]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

from baselines.evaluation import EVAL_SEED_BASE, LocalRayCluster, VideoSpec, evaluate_all

DOCK = "auv_envs/DockingStation-v2"
LARS = "auv_envs/LARSCapture-v0"
#: The board: short docking episodes of two agents, LARS episodes of one.
BOARD = dict(env_ids=[DOCK, LARS], agents=["random", "pd-state"],
             env_kwargs=[{DOCK: {"time_limit": 20.0}}])
NODES = 2


def timed(**kwargs) -> tuple[float, int]:
    """Seconds one evaluation of the board takes, and how many episodes it ran."""
    start = time.perf_counter()
    run = evaluate_all(**BOARD, **kwargs)
    seconds = time.perf_counter() - start
    failed = [r for r in run.rows if r.status != "ok"]
    if failed:
        raise RuntimeError(f"{len(failed)} episodes failed, e.g. {failed[0].error}")
    return seconds, run.stats.ran


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=4, help="episodes per pair (default 4)")
    parser.add_argument("--repeats", type=int, default=1,
                        help="evaluations on each backend, alternately; medians (default 1)")
    parser.add_argument("--cpus-per-node", type=int, default=1,
                        help="CPUs each Ray node offers (default 1)")
    parser.add_argument("--clips", action="store_true", help="record clips on both sides")
    args = parser.parse_args(argv)
    seeds = list(range(EVAL_SEED_BASE, EVAL_SEED_BASE + args.seeds))
    workers = NODES * args.cpus_per_node
    start = time.perf_counter()
    with LocalRayCluster(nodes=NODES, cpus=args.cpus_per_node) as cluster, \
            tempfile.TemporaryDirectory() as scratch:
        started = time.perf_counter() - start
        local_s, ray_s = [], []
        for repeat in range(args.repeats):
            local_video, ray_video = (VideoSpec(f"{scratch}/{side}{repeat}", (64, 48))
                                      if args.clips else None for side in ("local", "ray"))
            seconds, episodes = timed(seeds=seeds, workers=workers, video=local_video)
            local_s.append(seconds)
            ray_s.append(timed(seeds=seeds, backend="ray", ray_address=cluster.address,
                               video=ray_video)[0])
    local, ray = statistics.median(local_s), statistics.median(ray_s)
    print(f"board: {episodes} episodes ({', '.join(BOARD['agents'])} on "
          f"{', '.join(e.split('/')[1] for e in BOARD['env_ids'])} where they apply; "
          f"clips: {'yes' if args.clips else 'no'}), median of {args.repeats}")
    print(f"Ray cluster: {NODES} nodes x {args.cpus_per_node} CPU, started in {started:.1f} s "
          f"(not counted)")
    print(f"local backend, {workers} worker processes: {local:.1f} s")
    print(f"Ray backend, {NODES}-node local cluster:    {ray:.1f} s")
    print(f"ratio Ray / local: {ray / local:.2f}")


if __name__ == "__main__":
    main()
