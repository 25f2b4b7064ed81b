"""What one DDPG update costs on random frames and states (no simulator): its rate (:func:`bench_updates`), its
floating-point operations (:func:`update_flops`, counted by torch's FlopCounterMode) and its host-side work
(:func:`profile_update`: operator calls, host-device copies and synchronisations, counted by torch.profiler; on a
CPU build the host side only). `vision-rl bench ddpg` puts them side by side; the figures: docs/notes/ddpg.md."""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import replace
from typing import Any

import numpy as np
import torch

from vision_rl.ddpg.agent import ConvTrunk, DDPGAgent
from vision_rl.ddpg.config import BENCH_LAYOUTS, DDPGError, DDPGHyper
from vision_rl.envs.pixel_racing import PixelRacingConfig

#: torch.profiler's CUDA runtime calls that launch a kernel, copy between host and device, or wait for the device.
LAUNCH_EVENTS = ("cudaLaunchKernel", "cudaLaunchKernelExC", "cuLaunchKernel")
MEMCPY_EVENTS = ("cudaMemcpyAsync", "cudaMemcpy")
SYNC_EVENTS = ("cudaStreamSynchronize", "cudaDeviceSynchronize")


def random_batch(hyper: DDPGHyper, env: PixelRacingConfig, seed: int = 0) -> dict[str, Any]:
    """A batch of ``hyper.batch_size`` random transitions shaped as the replay samples them."""
    rng = np.random.default_rng(seed)
    n = hyper.batch_size

    def obs() -> dict[str, np.ndarray]:
        out = {
            "motion": rng.normal(size=(n, 15)).astype(np.float32),
            "goal": rng.normal(size=(n, 3)).astype(np.float32),
        }
        if env.frames:
            out["image"] = rng.integers(0, 256, (n, *env.image_hw_px, 3), dtype=np.uint8)
        return out

    return {
        "obs": obs(),
        "next_obs": obs(),
        "action": rng.uniform(0, 1, (n, 4)).astype(np.float32),
        "reward": rng.normal(size=n).astype(np.float32),
        "terminated": np.zeros(n, bool),
    }


def bench_updates(
    hyper: DDPGHyper,
    env: PixelRacingConfig,
    updates: int = 10,
    warmup: int = 2,
    seed: int = 0,
    layout: str = "",
    device: str = "cpu",
) -> dict[str, float]:
    """Updates per second at ``hyper.batch_size`` on random frames and states (what the network costs, no sim), and
    the process's CPU time per update (``cpu_ms_per_update``, all its threads): on a loaded machine the figure to
    compare, the wall clock's share of the cores being other jobs' choice.

    ``layout`` overrides ``hyper.channels_last``: ``eager`` (NCHW), ``channels_last``, or ``compiled`` (channels-last
    with every conv trunk through ``torch.compile``; its compilation happens in the untimed warm-up updates). On a
    GPU the batch is copied from the host in every update, as in training, and the clock waits for the GPU."""
    if layout and layout not in BENCH_LAYOUTS:
        raise DDPGError(f"layout must be one of {BENCH_LAYOUTS}, got {layout!r}")
    if layout:
        hyper = replace(hyper, channels_last=layout != "eager")
    agent = DDPGAgent(hyper, env, seed=seed, device=device)
    if layout == "compiled":
        for net in (agent.actor, agent.critic, agent.actor_target, agent.critic_target):
            if isinstance(getattr(net, "trunk", None), ConvTrunk):
                net.trunk.net = torch.compile(net.trunk.net)
    batch = random_batch(hyper, env, seed)
    sync = torch.cuda.synchronize if agent.device.type == "cuda" else (lambda: None)
    for _ in range(warmup):
        agent.update(batch)
    sync()
    t0, cpu0 = time.perf_counter(), time.process_time()
    for _ in range(updates):
        agent.update(batch)
    sync()
    dt, cpu_s = time.perf_counter() - t0, time.process_time() - cpu0
    # The process's CPU time beside the wall clock: on a shared machine the wall clock counts other jobs' turns.
    return {
        "updates_per_s": updates / dt,
        "ms_per_update": 1000 * dt / updates,
        "cpu_ms_per_update": 1000 * cpu_s / updates,
    }


def update_flops(hyper: DDPGHyper, env: PixelRacingConfig, seed: int = 0) -> int:
    """Floating-point operations of one update (forward and backward passes of every network it runs; a
    multiply-add counts 2), as torch's FlopCounterMode counts them on the CPU."""
    from torch.utils.flop_counter import FlopCounterMode

    agent = DDPGAgent(hyper, env, seed=seed)
    batch = random_batch(hyper, env, seed)
    with FlopCounterMode(display=False) as counter:
        agent.update(batch)
    return int(counter.get_total_flops())


def profile_update(
    hyper: DDPGHyper, env: PixelRacingConfig, updates: int = 3, seed: int = 0, device: str = "cpu"
) -> dict[str, float]:
    """Per update, from torch.profiler (after one unprofiled update): ``aten_ops`` (operator calls the host
    dispatches, nested ones included), ``leaf_ops`` (those that call no other: on a GPU each that computes is a
    kernel launch), ``optimizer_ops`` (the leaf ops inside the two Adam steps), ``item_reads`` (``.item()`` calls: on
    a GPU a wait for the device unless the tensor is on the host), and on a GPU ``kernel_launches``, ``memcpy`` and
    ``device_syncs`` (CUDA runtime calls); 0 on a CPU build, which profiles the host side only."""
    from torch.profiler import ProfilerActivity, profile

    agent = DDPGAgent(hyper, env, seed=seed, device=device)
    batch = random_batch(hyper, env, seed)
    agent.update(batch)
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if agent.device.type == "cuda" else [])
    with profile(activities=activities) as prof:
        for _ in range(updates):
            agent.update(batch)
    events = list(prof.events())
    aten = [e for e in events if e.name.startswith("aten::")]
    calls = {id(e.cpu_parent) for e in aten if e.cpu_parent is not None}
    leaves = [e for e in aten if id(e) not in calls]

    def in_optimizer(event: Any) -> bool:
        while event is not None:
            if event.name.startswith("Optimizer.step"):
                return True
            event = event.cpu_parent
        return False

    names = Counter(e.name for e in events)
    return {
        "aten_ops": len(aten) / updates,
        "leaf_ops": len(leaves) / updates,
        "optimizer_ops": sum(map(in_optimizer, leaves)) / updates,
        "item_reads": names["aten::item"] / updates,
        "kernel_launches": sum(names[n] for n in LAUNCH_EVENTS) / updates,
        "memcpy": sum(names[n] for n in MEMCPY_EVENTS) / updates,
        "device_syncs": sum(names[n] for n in SYNC_EVENTS) / updates,
    }
