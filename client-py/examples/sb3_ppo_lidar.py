"""Train, export, race: PPO (Stable-Baselines3) learns to lap on the LIDAR scan, the
policy is exported to ONNX, checked against Paddock's Rust runtime and benchmarked with
`paddock benchmark b1 --driver model.onnx`, next to the built-in drivers.

    pip install stable-baselines3 onnx onnxruntime   # SB3 brings torch
    python client-py/examples/sb3_ppo_lidar.py --steps 400000 --out ppo_lidar.onnx

The observation is the ONNX contract's (docs/onnx.md): the scan (metres) and the car's
speed. Training reads 84 beams over the LIDAR's 4.7 rad, which point where every 13th
beam of the car's 1080 points (1079 = 13 x 83): the exported model takes the 1080-beam scan a
Paddock car gives and picks those beams itself, so it drives in `paddock benchmark`,
`paddock demo` and `paddock bridge drive --driver ppo_lidar.onnx` unchanged, and training
casts 13 times fewer rays. The policy acts every FRAME_SKIP physics steps; the model says
so in its metadata (`paddock.action_repeat`).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import time

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.vec_env import VecEnvWrapper, VecMonitor

from paddock import onnx as ponnx
from paddock import sb3
from paddock.server import find_paddock

KEYS = ("scans", "linear_vels_x")
FRAME_SKIP = 4   # 25 actions per simulated second
CAR_BEAMS = 1080  # the vehicle's LIDAR, what the exported model takes
STRIDE = 13      # training's beams: every 13th of the car's
TRAIN_BEAMS = (CAR_BEAMS - 1) // STRIDE + 1  # 84, over the same field of view
CLIP = 10.0      # ranges beyond 10 m read as 10 m
SPEED = (0.5, 7.0)  # the speeds the policy may ask for, m/s


class LidarFeatures(BaseFeaturesExtractor):
    """The scan clipped to CLIP m and scaled to [0, 1], and the speed / 10."""

    def __init__(self, observation_space) -> None:
        super().__init__(observation_space,
                         features_dim=observation_space["scans"].shape[0] + 1)

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        scans = torch.clamp(obs["scans"], 0.0, CLIP) / CLIP
        return torch.cat([scans, obs["linear_vels_x"] / 10.0], dim=1)


class UnitActions(VecEnvWrapper):
    """The policy acts in [-1, 1]^2: steering scaled to the car's limit, speed to SPEED
    (a better-conditioned problem for PPO's Gaussian policy); the exported model applies
    the same map."""

    def __init__(self, venv: sb3.VecEnv) -> None:
        from gymnasium import spaces

        self.steer_max = float(venv.action_space.high[0])
        super().__init__(venv, action_space=spaces.Box(-1.0, 1.0, (2,), np.float32))

    def to_car(self, a: np.ndarray) -> np.ndarray:
        a = np.clip(a, -1.0, 1.0)
        lo, hi = SPEED
        return np.stack([a[:, 0] * self.steer_max, lo + (a[:, 1] + 1.0) * 0.5 * (hi - lo)],
                        axis=1).astype(np.float32)

    def step_async(self, actions: np.ndarray) -> None:
        self.venv.step_async(self.to_car(np.asarray(actions)))

    def step_wait(self):
        return self.venv.step_wait()

    def reset(self):
        return self.venv.reset()


class Exported(torch.nn.Module):
    """The deterministic policy as Paddock runs it: raw inputs -> [steer rad, speed m/s]."""

    def __init__(self, model: PPO, steer_max: float) -> None:
        super().__init__()
        self.policy = model.policy
        self.steer_max = steer_max

    def forward(self, scans: torch.Tensor, linear_vels_x: torch.Tensor) -> torch.Tensor:
        # the car's 1080 beams -> training's 84 (the same angles)
        obs = {"scans": scans[:, ::STRIDE], "linear_vels_x": linear_vels_x}
        features = self.policy.extract_features(obs, self.policy.pi_features_extractor)
        latent = self.policy.mlp_extractor.forward_actor(features)
        a = torch.clamp(self.policy.action_net(latent), -1.0, 1.0)
        lo, hi = SPEED
        steer = a[:, 0:1] * self.steer_max
        speed = lo + (a[:, 1:2] + 1.0) * 0.5 * (hi - lo)
        return torch.cat([steer, speed], dim=1)


class Progress(BaseCallback):
    """Prints the mean episode progress and lap count every `every` steps."""

    def __init__(self, every: int) -> None:
        super().__init__()
        self.every, self.next = every, every
        self.t0 = time.perf_counter()

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.next:
            self.next += self.every
            eps = list(self.model.ep_info_buffer)
            r = np.mean([e["r"] for e in eps]) if eps else float("nan")
            laps = [i.get("laps", 0) for i in self.locals["infos"]]
            print(f"{self.num_timesteps:>9} steps  {time.perf_counter() - self.t0:7.0f} s  "
                  f"episode return {r:7.1f}  laps now {laps}", flush=True)
        return True


def export(model: PPO, steer_max: float, path: str) -> None:
    import onnx

    net = Exported(model, steer_max).eval()
    scans = torch.full((1, CAR_BEAMS), 5.0)
    vx = torch.zeros((1, 1))
    torch.onnx.export(net, (scans, vx), path, input_names=list(KEYS), output_names=["action"],
                      dynamic_axes={"scans": {0: "batch"}, "linear_vels_x": {0: "batch"},
                                    "action": {0: "batch"}},
                      opset_version=17, dynamo=False)
    m = onnx.load(path)
    for key, value in [("paddock.action_repeat", str(FRAME_SKIP)), ("paddock.lidar_fov", "4.7")]:
        entry = m.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(m, path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=400_000, help="PPO environment steps")
    ap.add_argument("--envs", type=int, default=8, help="envs in the one session")
    ap.add_argument("--map", default="lakeside")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="ppo_lidar.onnx", help="the exported model")
    ap.add_argument("--endpoint", default=None, help="a broker (default: a local paddock serve)")
    ap.add_argument("--threads", type=int, default=0, help="the local server's threads")
    ap.add_argument("--episodes", type=int, default=10, help="B1 episodes")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke run: 2048 steps on 2 envs, 1 B1 episode (learns nothing)")
    args = ap.parse_args()
    if args.quick:
        args.steps, args.envs, args.episodes = 2048, 2, 1
    torch.set_num_threads(1)

    env = sb3.VecEnv(args.envs, args.endpoint, keys=KEYS, map=args.map, seed=args.seed,
                     num_beams=TRAIN_BEAMS, frame_skip=FRAME_SKIP, time_limit=60.0, laps=2,
                     reward={"progress": 1.0, "collision": -20.0}, threads=args.threads)
    steer_max = float(env.action_space.high[0])
    venv = VecMonitor(UnitActions(env))
    model = PPO("MultiInputPolicy", venv, seed=args.seed, n_steps=512, batch_size=512,
                n_epochs=10, learning_rate=3e-4, gamma=0.99, gae_lambda=0.95, ent_coef=0.0,
                policy_kwargs={"features_extractor_class": LidarFeatures,
                               "net_arch": {"pi": [64, 64], "vf": [64, 64]},
                               "activation_fn": torch.nn.Tanh}, verbose=0)
    t0 = time.perf_counter()
    model.learn(total_timesteps=args.steps, callback=Progress(max(args.steps // 20, 1)))
    train_s = time.perf_counter() - t0
    venv.close()

    export(model, steer_max, args.out)
    report = ponnx.check(args.out, samples=32)
    print(f"exported {args.out}: onnxruntime vs Paddock's runtime, largest difference "
          f"{report.max_abs_diff:.2e}")
    out = subprocess.run([os.environ.get("PADDOCK_BIN") or find_paddock(), "benchmark", "b1",
                          "--driver", args.out, "--map", args.map, "--episodes",
                          str(args.episodes), "--laps", "1", "--json"],
                         capture_output=True, text=True, check=True)
    b1 = json.loads(out.stdout)
    print(json.dumps({"train_seconds": round(train_s, 1), "steps": args.steps,
                      "b1_lap_time_mean": b1["lap_time_mean"], "b1_lap_time_std": b1["lap_time_std"],
                      "b1_success_rate": b1["success_rate"], "b1_crash_rate": b1["crash_rate"]}))


if __name__ == "__main__":
    main()
