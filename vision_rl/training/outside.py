"""The door for agents trained outside the project: :func:`evaluate` (``vision_rl.evaluate``) times any callable from
a batch of a registered environment's observations to a batch of its actions with the one lap-time protocol and
stores the record where ``vision-rl leaderboard`` finds it, under the agent's name.

The protocol drives the agent through :class:`~vision_rl.training.artifact.PolicyDriver` with what the environment
``gymnasium.make(env_id, **env_kwargs)`` would give it: its track and car, its control step, its observation (the
same normalisation) and its action space (mapped to the physical ``[steer rad, omega]`` by the environment's own
``physical_actions`` when it has one, else linearly from its action box). ``vision-rl evaluate --python
module:function`` and ``--policy agent.zip --env-id ...`` come through here too: a Stable-Baselines3 zip is read
from its tensors and plain JSON fields (:func:`read_sb3_actor`), never from its pickled parts.

Example, a stock Stable-Baselines3 agent (the README's quick start)::

    import gymnasium as gym
    import vision_rl
    from stable_baselines3 import PPO

    env = gym.make("vision_rl/TimeTrial-v1", track="technical")
    model = PPO("MlpPolicy", env).learn(200_000)
    record = vision_rl.evaluate(
        lambda obs: model.predict(obs, deterministic=True)[0],
        env_id="vision_rl/TimeTrial-v1", name="ppo-200k", track="technical",
    )
    print(record["best_lap_time_s"], record["evaluation_json"])  # then: vision-rl leaderboard --track technical
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import io
import json
import os
import re
import sys
import warnings
import zipfile
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from vision_rl.envs.core import RacingConfig
from vision_rl.envs.observations import ObsNormalizer
from vision_rl.envs.racing_env import action_space as physical_action_space
from vision_rl.files import file_sha256, first_line
from vision_rl.training.artifact import SIDECAR_NAME, PolicyDriver
from vision_rl.training.evaluate import EVALUATION_NAME, ProtocolRun, timed_record, write_record
from vision_rl.training.persist import DAMAGED_FILE_ERRORS

#: Where an outside agent's record goes under the leaderboard's folder: ``<runs>/<name as a folder>/evaluation.json``.
AGENT_FOLDER_CHARS = re.compile(r"[^A-Za-z0-9._-]+")


def evaluate(
    predict: Any,
    *,
    env_id: str,
    name: str,
    runs: str | os.PathLike[str] = "runs",
    seeds: int = 3,
    laps: int = 2,
    seed: int = 0,
    time_limit_s: float = 0.0,
    write: bool = True,
    device: str = "cpu",
    **env_kwargs: Any,
) -> dict[str, Any]:
    """Time an agent trained anywhere with the lap-time protocol and put it on the leaderboard.

    Args:
        predict: observations -> actions for a batch: exactly what ``gymnasium.make(env_id, **env_kwargs)`` gives,
            one row per car (``(n, 38)`` float32 for ``vision_rl/TimeTrial-v1``; a dict of batched arrays for a
            ``Dict`` space), to ``(n, action_dim)`` actions in that environment's action space. ``n`` is 3: the
            starts in batches of 3, the last padded with copies of its last start (docs/protocol.md says why). A
            numpy function, a ``torch.nn.Module`` (called in eval mode, without gradients, on a tensor of the batch)
            or an object with Stable-Baselines3's ``predict(obs, deterministic=True)`` (a trained ``PPO``/``SAC``).
        env_id: a registered ``vision_rl/...`` racing id (TimeTrial, Overtaking).
        name: the agent's row on the leaderboard; the record goes to ``<runs>/<name>/evaluation.json``.
        runs: the folder ``vision-rl leaderboard --runs`` searches (its default: ``runs``).
        seeds, laps, seed, time_limit_s: the protocol's start seeds (``seed`` ... ``seed + seeds - 1``), laps (the
            last one scored) and time limit per run, s (0: 3 x the limit lap time per lap).
        write: store the record (False: only return it).
        device: vision with an ``encoder``: where the encoder runs.
        env_kwargs: the environment's arguments, as ``gymnasium.make`` takes them: ``track``, ``car``,
            ``observation``...; for vision, ``encoder`` (a ``ckpt.pt`` path or a loaded encoder) makes the
            observation the vector ``[embedding, 11 features]`` instead of the frame and features.

    Returns:
        The record ``vision-rl evaluate`` writes (:func:`vision_rl.evaluation.leaderboard.evaluation_record`), with
        ``evaluation_json``, the file written, when ``write``.

    Example::

        import gymnasium as gym
        import vision_rl
        from stable_baselines3 import PPO

        env = gym.make("vision_rl/TimeTrial-v1", track="technical")
        model = PPO("MlpPolicy", env).learn(200_000)
        record = vision_rl.evaluate(
            lambda obs: model.predict(obs, deterministic=True)[0],
            env_id="vision_rl/TimeTrial-v1", name="ppo-200k", track="technical",
        )
        print(record["best_lap_time_s"], record["evaluation_json"])  # vision-rl leaderboard --track technical
    """
    encoder = env_kwargs.pop("encoder", None)
    run = ProtocolRun(laps=laps, seeds=seeds, seed=seed, time_limit_s=time_limit_s)
    return evaluate_agent(predict, env_id, name, env_kwargs, run, runs, write, encoder, device)


def evaluate_agent(
    predict: Any,
    env_id: str,
    name: str,
    env_kwargs: Mapping[str, Any],
    run: ProtocolRun,
    runs: str | os.PathLike[str] = "runs",
    write: bool = True,
    encoder: Any = None,
    device: str = "cpu",
    encoder_runtime: str = "auto",
    source: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """:func:`evaluate` with every option of ``vision-rl evaluate`` (``run``: plot, video, trace, sections...).
    ``source``: what the record says the agent is (``python``, ``policy``...) and ``remeasure``, how to time it
    again (the leaderboard says so when the protocol changes)."""
    run.check()
    out = agent_record_path(runs, name)
    env = describe_env(env_id, env_kwargs)
    frames_encoder, encoder_sha256 = _frames_encoder(encoder, env, device, encoder_runtime)
    if frames_encoder is not None and tuple(env.config.image_hw_px) != tuple(frames_encoder.input_hw_px):
        env_kwargs = _frames_for(frames_encoder, env_id, env_kwargs)
        env = describe_env(env_id, env_kwargs)
    check_spaces = getattr(predict, "check_spaces", None)
    if callable(check_spaces):
        check_spaces(env.observation_space, env.action_space)
    checked = CheckedPredict(as_batch_predict(predict), env, watch_observations=frames_encoder is None)
    identity = {
        "driver": "policy",
        "agent": "outside",
        "observation": env.config.observation,
        "env_id": env_id,
        "env_kwargs": json.loads(json.dumps(dict(env_kwargs), default=str)),
        "encoder_sha256": encoder_sha256,
        "remeasure": f"vision_rl.evaluate(predict, env_id={env_id!r}, name={name!r}, ...)",
        **(source or {}),
    }
    normalizer = None if frames_encoder is not None else env.normalizer
    driver = PolicyDriver.for_config(checked, env.config.observation, normalizer, frames_encoder, env.config, identity)
    result = timed_record(driver, env.config, name, run, frames_encoder)
    return write_record(result, out) if write else result


def _frames_for(encoder: Any, env_id: str, env_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """``env_kwargs`` rendering the frames the encoder reads (as train-policy does), unless the user chose others."""
    height, width = encoder.input_hw_px
    if "image_hw_px" in env_kwargs:
        chosen = tuple(env_kwargs["image_hw_px"])
        raise ValueError(
            f"{env_id}: image_hw_px={chosen} but the encoder reads {height} x {width} frames; leave image_hw_px out"
        )
    return {**env_kwargs, "image_hw_px": (height, width)}


def agent_record_path(runs: str | os.PathLike[str], name: str) -> Path:
    """``<runs>/<name>/evaluation.json`` (the name's characters other than letters, digits, ``.``, ``_`` and ``-``
    become ``-`` in the folder's name); refused for an empty name or a train-policy run's folder."""
    folder = AGENT_FOLDER_CHARS.sub("-", str(name)).strip("-.")
    if not str(name).strip() or not folder:
        raise ValueError(f"an outside agent needs a name (its row on the leaderboard), got {name!r}")
    path = Path(runs) / folder / EVALUATION_NAME
    if (path.parent / SIDECAR_NAME).exists():
        raise ValueError(f"{path.parent} is a train-policy run (it has {SIDECAR_NAME}): give the agent another name")
    return path


@dataclass(frozen=True)
class EnvFacts:
    """What the protocol's driver takes from a registered environment."""

    env_id: str
    config: RacingConfig
    normalizer: ObsNormalizer | None
    observation_space: spaces.Space
    action_space: spaces.Box
    to_physical: Callable[[np.ndarray], np.ndarray]
    """Actions (n, action_dim) in ``action_space`` -> (n, 2) ``[steer rad, omega]`` as the environment maps them."""


def describe_env(env_id: str, env_kwargs: Mapping[str, Any]) -> EnvFacts:
    """Make ``env_id`` with ``env_kwargs`` once and read its config, observation normaliser and spaces."""
    if env_id not in gym.registry:
        ours = sorted(k for k in gym.registry if k.startswith("vision_rl/"))
        raise ValueError(f"{env_id!r} is not a registered environment; vision_rl's: {', '.join(ours)}")
    if "pixel_racing" in str(gym.spec(env_id).entry_point):
        raise ValueError(f"{env_id} (the DDPG paper's environment) is timed by vision-rl evaluate-ddpg, not here")
    try:
        with warnings.catch_warnings():  # an agent is timed on the version it was trained on, newer ones or not
            warnings.filterwarnings("ignore", message=".*is out of date", category=DeprecationWarning)
            env = gym.make(env_id, **env_kwargs)
    except (TypeError, ValueError, OSError) as exc:
        raise ValueError(f"{env_id}: {first_line(exc)}") from None
    try:
        base = env.unwrapped
        config = getattr(base, "config", None)
        if not isinstance(config, RacingConfig):
            raise ValueError(f"{env_id} is not one of vision_rl's racing environments (TimeTrial, Overtaking)")
        normalizer = base.core.observer.normalizer
        to_physical = _action_map(env_id, base, env.action_space)
        return EnvFacts(env_id, config, normalizer, env.observation_space, env.action_space, to_physical)
    finally:
        env.close()


def _action_map(env_id: str, base: gym.Env, space: spaces.Space) -> Callable[[np.ndarray], np.ndarray]:
    """The environment's own map, ``physical_actions(actions, env.normalized_spaces)`` of its module, when it has
    one; else the identity for the physical box, or the linear map of a finite box onto it (actions clipped)."""
    convert = getattr(sys.modules.get(type(base).__module__), "physical_actions", None)
    if callable(convert) and hasattr(base, "normalized_spaces"):
        normalized = bool(base.normalized_spaces)
        return lambda actions: np.asarray(convert(actions, normalized), dtype=np.float64)
    physical = physical_action_space()
    if not isinstance(space, spaces.Box) or space.shape != physical.shape:
        raise ValueError(f"{env_id} acts in {space}, which the protocol cannot map to [steer rad, omega]")
    if np.array_equal(space.low, physical.low) and np.array_equal(space.high, physical.high):
        return lambda actions: actions
    if not (np.isfinite(space.low).all() and np.isfinite(space.high).all()):
        raise ValueError(f"{env_id} acts in an unbounded {space}: no map to [steer rad, omega]")
    low, high = space.low.astype(np.float64), space.high.astype(np.float64)
    scale = (physical.high.astype(np.float64) - physical.low) / (high - low)
    return lambda actions: physical.low + (np.clip(actions, low, high) - low) * scale


def _frames_encoder(encoder: Any, env: EnvFacts, device: str, runtime: str) -> tuple[Any, str | None]:
    """(the frame encoder, its checkpoint's SHA-256) for ``encoder`` (a path or a loaded encoder), or (None, None)."""
    if encoder is None or encoder == "":
        return None, None
    if not env.config.kind.sees_frames:
        raise ValueError(f"the {env.config.observation!r} observation takes no encoder (vision does)")
    if isinstance(encoder, str | os.PathLike):
        from vision_rl.phase1_repr.checkpoint import load_encoder

        if not Path(encoder).is_file():
            raise ValueError(f"encoder checkpoint {encoder} not found")
        encoder = load_encoder(encoder, device=device, runtime=runtime)
    if not (hasattr(encoder, "rep_dim") and hasattr(encoder, "input_hw_px")):
        raise ValueError(
            "encoder must be a ckpt.pt path or a loaded encoder (frames -> (n, rep_dim), with rep_dim and input_hw_px)"
        )
    return encoder, getattr(encoder, "sha256", None)


def as_batch_predict(agent: Any) -> Callable[[Any], Any]:
    """``agent`` as a function of a batch of observations: a ``torch.nn.Module`` in eval mode without gradients, an
    object with Stable-Baselines3's ``predict`` deterministic, any other callable as it is."""
    torch = sys.modules.get("torch")  # a module agent was made with torch: it is imported already
    if torch is not None and isinstance(agent, torch.nn.Module):
        agent.eval()
        device = next(agent.parameters(), torch.empty(0)).device

        def module_predict(obs: Any) -> Any:
            with torch.no_grad():
                if isinstance(obs, dict):
                    return agent({k: torch.as_tensor(v, device=device) for k, v in obs.items()})
                return agent(torch.as_tensor(obs, device=device))

        return module_predict
    if not callable(agent) and callable(getattr(agent, "predict", None)):
        return lambda obs: agent.predict(obs, deterministic=True)[0]
    if not callable(agent):
        raise ValueError(f"the agent must be callable (observations -> actions), got a {type(agent).__name__}")
    return agent


class CheckedPredict:
    """An agent's batch function as the protocol's driver calls it: the observations checked once against the
    environment's space, the actions refused unless one finite row per observation, then mapped to physical units."""

    def __init__(self, predict: Callable[[Any], Any], env: EnvFacts, watch_observations: bool = True) -> None:
        self.predict, self.env = predict, env
        self.watch_observations = watch_observations
        self.action_dim = int(np.prod(env.action_space.shape))

    def __call__(self, obs: Any) -> np.ndarray:
        if self.watch_observations:
            _check_observations(obs, self.env)
            self.watch_observations = False
        n = len(obs["features"] if isinstance(obs, dict) else obs)
        out = self.predict(obs)
        if isinstance(out, tuple):
            raise ValueError(
                "the agent returned a tuple: return the actions alone (Stable-Baselines3: "
                "model.predict(obs, deterministic=True)[0])"
            )
        if hasattr(out, "detach"):  # a torch tensor
            out = out.detach().cpu().numpy()
        try:
            actions = np.asarray(out, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"the agent's actions are not an array of numbers: {first_line(exc)}") from None
        if actions.shape != (n, self.action_dim):
            raise ValueError(
                f"the agent returned actions of shape {actions.shape} for {n} observations: give one row per "
                f"observation, ({n}, {self.action_dim}), in {self.env.env_id}'s action space"
            )
        if not np.isfinite(actions).all():
            raise ValueError(f"the agent returned non-finite actions: {actions.tolist()}")
        return self.env.to_physical(actions)


def _check_observations(obs: Any, env: EnvFacts) -> None:
    """Refuse a batch that is not what the environment gives (a new env version the driver does not make)."""
    space = env.observation_space
    parts = space.spaces if isinstance(space, spaces.Dict) else {"": space}
    given = obs if isinstance(obs, dict) else {"": obs}
    same = set(parts) == set(given) and all(
        np.asarray(given[k]).shape[1:] == parts[k].shape and np.asarray(given[k]).dtype == parts[k].dtype for k in parts
    )
    if not same:
        shapes = {k: (np.asarray(v).shape[1:], str(np.asarray(v).dtype)) for k, v in given.items()}
        raise ValueError(
            f"{env.env_id} observes {space}, but the protocol's driver makes {shapes}: this environment version "
            "cannot be timed here yet"
        )


# ----------------------------------------------------------------------------------------- --python module:function


def load_python_agent(spec: str) -> Any:
    """The object ``spec`` names: ``module:attribute`` (imported with the current folder on ``sys.path``) or
    ``path/to/file.py:attribute`` (its folder on ``sys.path`` while it is imported). The attribute is the agent
    itself, as :func:`evaluate` takes it (a predict function, a torch module, an SB3 model), not a factory: an agent
    built at load time is assigned at module level (``predict = make_agent()``). Importing runs the module's code,
    as ``python -c "import module"`` would."""
    module_name, sep, attribute = str(spec).rpartition(":")
    if not sep or not module_name or not attribute:
        raise ValueError(f"--python takes module:function or path/to/file.py:function, got {spec!r}")
    try:
        if module_name.endswith(".py"):
            module = _import_file(Path(module_name))
        else:
            with _on_sys_path(os.getcwd()):
                module = importlib.import_module(module_name)
    except (ImportError, SyntaxError) as exc:
        raise ValueError(f"--python {spec}: cannot import {module_name}: {first_line(exc)}") from None
    agent: Any = module
    for part in attribute.split("."):
        if not hasattr(agent, part):
            raise ValueError(f"--python {spec}: {module_name} has no attribute {attribute!r}")
        agent = getattr(agent, part)
    return agent


def _import_file(path: Path) -> Any:
    if not path.is_file():
        raise ValueError(f"--python: no such file {path}")
    name = f"vision_rl_agent_{AGENT_FOLDER_CHARS.sub('_', path.stem)}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ValueError(f"--python: {path} cannot be imported")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        with _on_sys_path(str(path.resolve().parent)):  # the file imports its neighbours as a script would
            spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return module


@contextlib.contextmanager
def _on_sys_path(folder: str) -> Iterator[None]:
    """``folder`` first on ``sys.path`` while a module is imported (nothing added when it is there already)."""
    added = folder not in sys.path
    if added:
        sys.path.insert(0, folder)
    try:
        yield
    finally:
        if added and folder in sys.path:
            sys.path.remove(folder)


# ---------------------------------------------------------------------------------- --policy agent.zip (SB3, no pickle)

#: Activations an SB3 zip may name in its policy_kwargs (by their torch class name); others are refused.
SB3_ACTIVATIONS = ("ReLU", "Tanh", "ELU", "LeakyReLU", "SiLU", "GELU", "Sigmoid")
#: The actor's layers of each SB3 layout (a prefix of numbered Linear layers, then the output layer) and the
#: activation its algorithms default to.
SB3_LAYOUTS = {
    "actor-critic (PPO, A2C)": ("mlp_extractor.policy_net.", "action_net.", "Tanh"),
    "SAC": ("actor.latent_pi.", "actor.mu.", "ReLU"),
    "TD3, DDPG": ("actor.mu.", None, "ReLU"),
}


@dataclass
class SB3Actor:
    """The deterministic actor of a Stable-Baselines3 MLP policy rebuilt from its tensors: observations (n, d) ->
    actions (n, action_dim) in the zip's action box, as ``model.predict(obs, deterministic=True)`` gives them."""

    path: Path
    algorithm: str
    layers: list[tuple[Any, Any]]
    """(weight, bias) of each Linear layer of the actor, the last one the output."""
    activation: Any
    squashed: bool
    """SAC, TD3: tanh outputs scaled onto the box; PPO, A2C: Gaussian means clipped to it."""
    obs_dim: int
    action_low: np.ndarray
    action_high: np.ndarray
    num_timesteps: int

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        import torch

        with torch.no_grad():
            x = torch.as_tensor(np.asarray(obs)).float()
            for k, (weight, bias) in enumerate(self.layers):
                x = torch.nn.functional.linear(x, weight, bias)
                if k < len(self.layers) - 1:
                    x = self.activation(x)
            actions = (torch.tanh(x) if self.squashed else x).numpy()
        # As SB3's predict, in float32: a squashed action scaled onto the box, a Gaussian mean clipped to it.
        if self.squashed:
            return self.action_low + (0.5 * (actions + 1.0) * (self.action_high - self.action_low))
        return np.clip(actions, self.action_low, self.action_high)

    def check_spaces(self, observation_space: spaces.Space, action_space: spaces.Space) -> None:
        """Refuse an environment this actor was not trained for (other inputs or another action box); for its own,
        act in the environment's bounds as they are (the zip writes them to 8 digits)."""
        if observation_space.shape != (self.obs_dim,):
            raise ValueError(f"{self.path} reads {self.obs_dim} inputs, the environment gives {observation_space}")
        same_box = isinstance(action_space, spaces.Box) and action_space.shape == self.action_low.shape
        if not same_box or not (
            np.allclose(action_space.low, self.action_low, rtol=1e-6)
            and np.allclose(action_space.high, self.action_high, rtol=1e-6)
        ):
            raise ValueError(
                f"{self.path} acts in a box [{self.action_low}, {self.action_high}], the environment in {action_space}"
            )
        self.action_low, self.action_high = action_space.low, action_space.high


def read_sb3_actor(path: str | os.PathLike[str]) -> SB3Actor:
    """The actor of a Stable-Baselines3 zip (PPO, A2C, SAC, TD3, DDPG; MLP policy of a vector observation), read
    as ``convert-policy`` reads one (:func:`~vision_rl.training.persist.read_sb3_zip`): ``policy.pth`` with
    ``torch.load(weights_only=True)`` and the plain JSON fields of ``data``; its pickled parts are never read."""
    import torch

    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            with archive.open("policy.pth") as member:
                tensors = torch.load(io.BytesIO(member.read()), map_location="cpu", weights_only=True)
            data = json.loads(archive.read("data"))
    except DAMAGED_FILE_ERRORS as exc:
        raise ValueError(f"{path}: not a Stable-Baselines3 zip whose tensors load safely: {first_line(exc)}") from None
    if not isinstance(tensors, dict) or not isinstance(data, dict):
        raise ValueError(f"{path}: not a Stable-Baselines3 zip (no policy tensors and data)")
    if any("features_extractor" in key for key in tensors):
        raise ValueError(f"{path}: its policy has a features extractor with weights; only MLP policies are read")
    if data.get("use_sde"):
        raise ValueError(f"{path}: a gSDE policy (use_sde) is not read; train it without use_sde")
    algorithm, (hidden, output, default_activation) = _sb3_layout(path, tensors)
    layers = _numbered_layers(tensors, hidden)
    if output is not None:
        layers.append((tensors[output + "weight"], tensors[output + "bias"]))
    low, high = _sb3_action_box(path, data)
    return SB3Actor(
        path=path,
        algorithm=algorithm,
        layers=layers,
        activation=_sb3_activation(path, data.get("policy_kwargs"), default_activation),
        squashed=output != "action_net.",
        obs_dim=int(layers[0][0].shape[1]),
        action_low=low,
        action_high=high,
        num_timesteps=int(data.get("num_timesteps", 0) or 0),
    )


def _sb3_layout(path: Path, tensors: Mapping[str, Any]) -> tuple[str, tuple[str, str | None, str]]:
    for algorithm, (hidden, output, activation) in SB3_LAYOUTS.items():
        if f"{hidden}0.weight" in tensors and (output is None or f"{output}weight" in tensors):
            return algorithm, (hidden, output, activation)
    raise ValueError(f"{path}: not the zip of an SB3 MLP policy of PPO, A2C, SAC, TD3 or DDPG (no actor found)")


def _numbered_layers(tensors: Mapping[str, Any], prefix: str) -> list[tuple[Any, Any]]:
    """(weight, bias) of ``prefix{i}.weight`` for each numbered Linear layer, in order."""
    numbers = sorted(
        int(k[len(prefix) :].split(".")[0]) for k in tensors if re.fullmatch(rf"{re.escape(prefix)}\d+\.weight", k)
    )
    return [(tensors[f"{prefix}{i}.weight"], tensors[f"{prefix}{i}.bias"]) for i in numbers]


def _sb3_activation(path: Path, policy_kwargs: Any, default: str) -> Any:
    """The activation the zip's ``policy_kwargs`` name in plain text (``<class 'torch.nn...ReLU'>``), else the
    algorithm's default."""
    import torch

    named = (policy_kwargs or {}).get("activation_fn") if isinstance(policy_kwargs, dict) else None
    if named is None:
        return getattr(torch.nn, default)()
    match = re.search(r"torch\.nn\.modules\.activation\.(\w+)'", str(named))
    if match is None or match.group(1) not in SB3_ACTIVATIONS:
        raise ValueError(f"{path}: its activation {named} is not one of {', '.join(SB3_ACTIVATIONS)}")
    return getattr(torch.nn, match.group(1))()


def _sb3_action_box(path: Path, data: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The action box's bounds from the plain-text ``low`` and ``high`` SB3 writes beside the pickled space."""
    space = data.get("action_space")
    try:
        low, high = (np.array(str(space[k]).strip("[]").split(), dtype=np.float32) for k in ("low", "high"))
    except (TypeError, KeyError, ValueError):
        raise ValueError(f"{path}: its action space is not a box written in plain text") from None
    if low.shape != high.shape or not (np.isfinite(low).all() and np.isfinite(high).all()):
        raise ValueError(f"{path}: its action space is not a bounded box")
    return low, high


def sb3_zip_source(actor: SB3Actor) -> dict[str, Any]:
    """What a record says of an agent read from an SB3 zip."""
    return {
        "policy": str(actor.path),
        "policy_sha256": file_sha256(actor.path),
        "algorithm": actor.algorithm,
        "num_timesteps": actor.num_timesteps,
    }
