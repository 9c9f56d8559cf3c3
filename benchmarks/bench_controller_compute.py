"""Each controller's compute per control period, against the 1 ms period it must fit in.

For every controller (the baselines and the shipped policies) it runs episodes of a test condition
on the single environment, every imperfection on, and times each period's controller call,
``controller(obs, info)``: what ``run_episode`` calls between two control periods' physics, the
command from the observation and the controller's state update, not the physics. Each of
``--repeats`` rounds runs every controller's episode in turn (a busy spell of a shared machine is
spread over all of them); a controller's periods of every round are pooled. It reports their median
and 99th percentile, in µs, those of the periods where a policy acts (every ``decision_period``; a
baseline decides every period), and, for a policy, those of onnxruntime's inference of its ONNX
export (:mod:`microg_env.learning.onnx_export`) on each of the episode's observations, one at a
time, on one thread. Prints a Markdown table, and the machine it ran on.

Usage: ``python benchmarks/bench_controller_compute.py [--controllers pid,residual-sac-setpoint] [--condition N]
[--duration S] [--seed N] [--repeats N]``.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time

import numpy as np
import onnxruntime as ort

from microg_env.controllers import make_controller
from microg_env.controllers.base import tell_plants
from microg_env.controllers.registry import check_policy_folder, policy_folder
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.interface import BASELINES, CONTROLLER_NAMES
from microg_env.learning.onnx_export import INPUT, policy_model

#: Periods run before the timed episode (numba's cached kernels loaded, onnxruntime's first run).
WARM_UP = 20


def cpu_name() -> str:
    """The processor's model name (Linux's /proc/cpuinfo), else the platform's."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as info:
            for line in info:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def timed_episode(env: MicroGravityLandingEnv, controller, seed: int, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The wall time of each period's controller call, ns, and the observation it was given, over up to
    ``steps`` periods of the episode of ``seed`` (as ``run_episode`` drives it)."""
    obs, info = env.reset(seed=seed)
    controller.reset()
    tell_plants(controller, np.zeros(1, dtype=np.int64), [env.params], ideal_drive=env.core.rig.ideal_drive)
    times, observations = np.zeros(steps, dtype=np.int64), np.zeros((steps, obs.size))
    for k in range(steps):
        observations[k] = obs
        start = time.perf_counter_ns()
        action = controller(obs, info)
        times[k] = time.perf_counter_ns() - start
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return times[: k + 1], observations[: k + 1]
    return times, observations


def onnx_session(name: str) -> ort.InferenceSession:
    """onnxruntime's session of policy ``name``'s ONNX export, on one thread."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    model = policy_model(check_policy_folder(policy_folder(name))[1])
    return ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])


def onnx_times(session: ort.InferenceSession, observations: np.ndarray) -> np.ndarray:
    """The wall time of ``session``'s inference on each observation, one at a time, ns."""
    times = np.zeros(len(observations), dtype=np.int64)
    for k, row in enumerate(observations[:, None, :]):
        start = time.perf_counter_ns()
        session.run(None, {INPUT: row})
        times[k] = time.perf_counter_ns() - start
    return times


def quantiles_us(times_ns: np.ndarray) -> str:
    """The median and the 99th percentile of ``times_ns``, in µs, as two table cells."""
    median, p99 = np.percentile(times_ns, [50, 99]) / 1e3
    return f"{median:.1f} | {p99:.1f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controllers", default=",".join(CONTROLLER_NAMES))
    parser.add_argument("--condition", type=int, default=1)
    parser.add_argument("--duration", type=float, default=None, help="cap on the episode, s (default: the condition's)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=3, help="rounds, the controllers taken in turn in each")
    args = parser.parse_args(argv)
    names = args.controllers.split(",")
    envs = {name: MicroGravityLandingEnv(condition=args.condition) for name in names}
    period = envs[names[0]].settings.control_period_s
    duration = envs[names[0]].scenario.duration_s if args.duration is None else args.duration
    controllers = {name: make_controller(name, period) for name in names}
    sessions = {name: onnx_session(name) for name in names if name not in BASELINES}
    times = {name: [] for name in names}
    onnx = {name: [] for name in sessions}
    for name in names:  # numba's cached kernels loaded, onnxruntime's first runs
        _, observations = timed_episode(envs[name], controllers[name], args.seed, WARM_UP)
        if name in sessions:
            onnx_times(sessions[name], observations)
    for _ in range(args.repeats):
        for name in names:
            took, observations = timed_episode(envs[name], controllers[name], args.seed, round(duration / period))
            times[name].append(took)
            if name in sessions:
                onnx[name].append(onnx_times(sessions[name], observations))
    today = datetime.datetime.now(datetime.timezone.utc).date()
    print(
        f"{today}, {cpu_name()} ({os.cpu_count()} cores), Python {platform.python_version()}, numpy "
        f"{np.__version__}, onnxruntime {ort.__version__}; condition {args.condition}, seed {args.seed}, "
        f"{args.repeats} rounds"
    )
    print()
    print(
        "| controller | acts every [periods] | periods | median [µs] | p99 [µs] | acting: median [µs] "
        "| acting: p99 [µs] | p99 / period | ONNX: median [µs] | ONNX: p99 [µs] |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in names:
        every = 1 if name in BASELINES else controllers[name].acting.decision_period
        took = np.concatenate(times[name])
        acting = "— | —" if every == 1 else quantiles_us(np.concatenate([run[::every] for run in times[name]]))
        inference = quantiles_us(np.concatenate(onnx[name])) if name in onnx else "— | —"
        share = np.percentile(took, 99) / (period * 1e9)
        print(f"| `{name}` | {every} | {len(took)} | {quantiles_us(took)} | {acting} | {share:.1%} | {inference} |")
    for env in envs.values():
        env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
