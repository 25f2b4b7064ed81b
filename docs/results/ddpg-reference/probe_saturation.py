"""Why ours (no batch-norm) saturates on Pendulum-v1: every 100 updates, on the update's batch, the actor's mean
|pre-tanh| output and the share of states where dQ/da > 0, and the critic's loss. ``base``: our critic (state and
action pathways merged late); ``concat``: a diagnosis-only critic of SB3's shape (state and action concatenated into
one MLP of 150, 300, 300, 600); ``init``: our critic, the actor's output layer at PyTorch's default init. Usage:
``python probe_saturation.py base|concat|init SEED STEPS``; output: probe_saturation.txt (seed 2 at 2,000 steps, then
concat and init on seeds 1 and 2 at 5,000 steps)."""

import itertools
import sys

import numpy as np
import torch
from torch import nn

from vision_rl.ddpg import agent as A
from vision_rl.ddpg import reference as R

torch.set_num_threads(1)

mode, seed, steps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])


class ConcatCritic(nn.Module):  # SB3's critic shape, diagnosis only
    def __init__(self, task, batch_norm=True):
        super().__init__()
        self.scaled = A._Scaled(np.asarray(task.obs_offset), np.asarray(task.obs_scale))
        dims = [task.obs_dim + task.action_dim, 150, 300, 300, 600]
        layers = []
        for a, b in itertools.pairwise(dims):
            layers += [nn.Linear(a, b), nn.ReLU()]
        self.net = nn.Sequential(*layers, nn.Linear(600, 1))

    def forward(self, obs, action):
        return self.net(torch.cat([self.scaled(obs["state"]), action], 1)).squeeze(1)


if mode == "concat":
    A.VectorCritic = ConcatCritic
orig_update = A.DDPGAgent.update
log = []


def update(self, batch):
    out = orig_update(self, batch)
    if self.n_updates % 100 == 0:
        obs = A._to_torch(batch["obs"], self.device)
        with torch.no_grad():
            z = self.actor.out(self.actor.dense(self.actor.scaled(obs["state"])))
        a = torch.tanh(z).detach().requires_grad_(True)
        self.critic.eval()
        q = self.critic(obs, a).sum()
        (g,) = torch.autograd.grad(q, a)
        log.append(
            (
                self.n_updates,
                round(z.abs().mean().item(), 2),
                round((g > 0).float().mean().item(), 2),
                round(float(out["critic_loss"]), 2),
            )
        )
    return out


A.DDPGAgent.update = update
if mode == "init":
    orig = A._variance_scaling_
    A._variance_scaling_ = lambda lin, s: None  # PyTorch's default init of the output layer
r = R.run_reference(
    R.ReferenceRun(algo="ours", seed=seed, steps=steps, eval_every_steps=500, eval_episodes=2, final_eval_episodes=2)
)
print(mode, seed, [round(e["mean_return"]) for e in r["evaluations"]])
for row in log:
    print(row)
