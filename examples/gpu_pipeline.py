"""A GPU model in a component actor: 1080p frames at 30 Hz through ResNet-50 (fp16, CUDA), one
poisoned CUDA context (a device-side assert) mid-run, recovered by the fallback restart.

The GPU component is spawned (``start_method="spawn"``: CUDA does not survive ``fork``) and keeps a
warm standby (``standby=True``, unless ``GPU_STANDBY=0``): the standby has built and warmed its own
network in its own CUDA context, so the restart after the poisoned context is a takeover, not a
6.7 s start. Without torch and CUDA the same code runs a numpy stand-in (what CI runs); the bench
case ``gpu_pipeline`` runs it on a GPU (docs/guides/gpu.md).

Install: ``pip install -e .`` (the numpy stand-in needs no extra; on a GPU machine add torch and
torchvision yourself). Run: ``embagents supervise examples/gpu_pipeline.py`` (env: GPU_FRAMES, GPU_POISON_AT, GPU_OUT,
GPU_STANDBY). The same frames through the same network in one process, for comparison:
``python examples/gpu_pipeline.py`` (prints ``INPROC {json}``).
"""
from __future__ import annotations

import json
import os
import time
from typing import Any

import numpy as np

from embagents.components import Component
from embagents.events import Fallback, restart
from embagents.msgs import Image, String
from embagents.system import SYSTEM_STOP, System
from embagents.topic import Topic

OUT = os.environ.get("GPU_OUT", "/tmp/gpu_out")
FRAMES = int(os.environ.get("GPU_FRAMES", "600"))
POISON_AT = int(os.environ.get("GPU_POISON_AT", "300"))
STANDBY = os.environ.get("GPU_STANDBY", "1") == "1"
MARK = os.path.join(OUT, "poisoned.mark")
RATE = 30.0


def make_frame(i: int) -> np.ndarray:
    f = np.full((1080, 1920, 3), i % 251, np.uint8)
    f[::7, ::5, 1] = 200
    return f


class Net:
    """The same inference for the actor and the in-process baseline (torch + CUDA, or a numpy stand-in)."""

    def __init__(self) -> None:
        try:
            import torch
            import torchvision

            self.cuda = torch.cuda.is_available()
        except ImportError:
            self.cuda = False
        self.device = "cpu (numpy stand-in)"
        if self.cuda:
            self.torch = torch
            self.device = torch.cuda.get_device_name()
            self.model = torchvision.models.resnet50().cuda().eval().half()
            with torch.inference_mode():
                for _ in range(5):
                    self(make_frame(0))
        else:
            self.w = np.random.default_rng(0).standard_normal((64, 10)).astype(np.float32)

    def __call__(self, frame: np.ndarray) -> int:
        if not self.cuda:
            x = frame[::17, ::30, :].reshape(-1)[: 64 * 64].reshape(64, 64).astype(np.float32)
            return int((x @ self.w).argmax())
        torch = self.torch
        with torch.inference_mode():
            t = torch.from_numpy(frame).cuda()
            x = t.permute(2, 0, 1).unsqueeze(0).half().div_(255)
            x = torch.nn.functional.interpolate(x, size=(224, 224), mode="bilinear", align_corners=False)
            return int(self.model(x).argmax())

    def poison(self) -> None:
        if not self.cuda:
            raise RuntimeError("stand-in for: CUDA error: device-side assert triggered")
        torch = self.torch
        a = torch.zeros(4, device="cuda")
        idx = torch.tensor([1000], device="cuda")
        a[idx] = 1.0  # out of bounds on the device: a sticky device-side assert
        torch.cuda.synchronize()


class Frames(Component):
    allowed_outputs = {"Required": [Image]}

    def __init__(self, **kw: Any) -> None:
        self.i = 0
        self.frames = [make_frame(k) for k in range(4)]
        super().__init__(**kw)

    def _execution_step(self, **inputs: Any) -> None:
        self.i += 1  # until the sink stops the system
        self.publish(frames, Image(data=self.frames[self.i % 4], stamp=time.time(), frame_id=str(self.i)))


class GpuNet(Component):
    allowed_inputs = {"Required": [Image]}
    allowed_outputs = {"Required": [String]}

    def on_configure(self) -> None:
        # The GPU work belongs here, in the component's own (spawned) process, never at import.
        t0 = time.time()
        self.net = Net()
        print(f"gpunet: pid {os.getpid()} device={self.net.device} ready in {time.time() - t0:.2f} s", flush=True)
        super().on_configure()

    def _execution_step(self, **inputs: Any) -> None:
        img = inputs["frames"]
        seq = int(img.frame_id)
        self.handled = getattr(self, "handled", 0) + 1
        # After POISON_AT frames handled here (not frame POISON_AT: a slow start must not skip the fault).
        if self.handled >= POISON_AT and not os.path.exists(MARK):
            with open(MARK, "w") as f:
                f.write(str(time.time()))
            print(f"gpunet: poisoning the CUDA context at frame {seq} (pid {os.getpid()})", flush=True)
            self.net.poison()
        cls = self.net(img.data)
        self.publish(results, String(data=f"{img.stamp!r} {seq} {cls} {os.getpid()} {self.net.device}"))


class Sink(Component):
    allowed_inputs = {"Required": [String]}
    allowed_outputs = {"Required": [String]}

    def __init__(self, **kw: Any) -> None:
        self.rows: list[tuple[float, float, int, int]] = []
        self.device = ""
        self.done = False
        super().__init__(**kw)

    def on_message(self, topic_name: str, msg: Any, now: float | None = None) -> bool:
        if topic_name == "results":
            stamp, seq, _cls, pid, self.device = msg.data.split(" ", 4)
            self.rows.append((float(stamp), time.time(), int(seq), int(pid)))
        return super().on_message(topic_name, msg, now)

    def _execution_step(self, **inputs: Any) -> None:
        # FRAMES frames from the first result on (frames published before the GPU component was up
        # are not counted), or a minute of silence.
        if self.done or not self.rows:
            return
        first = self.rows[0][2]
        if self.rows[-1][2] < first + FRAMES - 1 and time.time() - self.rows[-1][1] < 60:
            return
        self.done = True
        rows = [r for r in self.rows if r[2] < first + FRAMES]
        lat = np.array([(b - a) * 1e3 for a, b, _, _ in rows])
        pids = sorted({p for *_, p in rows}, key=[p for *_, p in rows].index)
        arrivals = [b for _, b, _, _ in rows]
        gaps = np.diff(arrivals) * 1e3 if len(arrivals) > 1 else np.array([0.0])
        poisoned = float(open(MARK).read()) if os.path.exists(MARK) else None
        after = [b for _, b, s, p in rows if poisoned and b > poisoned and p != pids[0]]
        before = [(b - a) * 1e3 for a, b, _, _ in rows if poisoned is None or b < poisoned]
        steady = np.array(before[len(before) // 10:] or lat)  # the first tenth warms up
        res = {
            "device": self.device, "standby": STANDBY, "results": len(self.rows), "pids": pids,
            "latency_p50_ms": float(np.percentile(steady, 50)), "latency_p99_ms": float(np.percentile(steady, 99)),
            "latency_p50_after_ms": float(np.percentile(lat[-100:], 50)),
            "max_gap_ms": float(gaps.max()),
            "recovery_s": (after[0] - poisoned) if after and poisoned else None,
            "frames_missing": len(set(range(first, first + FRAMES)) - {s for _, _, s, _ in rows}),
        }
        print("RESULT " + json.dumps(res), flush=True)
        os.makedirs(OUT, exist_ok=True)
        with open(os.path.join(OUT, "pipeline.json"), "w") as f:
            json.dump(res, f)
        self.publish(stop, String(data="done"))


frames = Topic("frames", Image)
results = Topic("results", String, queue_size=1000, keep="all")
stop = Topic(SYSTEM_STOP, String)

system = System(
    [
        Frames(name="frames_src", outputs=[frames], trigger=RATE),
        GpuNet(name="gpunet", inputs=[frames], outputs=[results], trigger=frames, start_method="spawn",
               standby=STANDBY, fallback=Fallback(on_algorithm_fail=restart(), max_retries=3)),
        Sink(name="sink", inputs=[results], outputs=[stop], trigger=2.0),
    ],
    name="gpu",
)


def in_process(n: int = FRAMES) -> dict[str, Any]:
    """The same frames at the same 30 Hz through the same Net, in this one process."""
    t0 = time.time()
    net = Net()
    ready = time.time() - t0
    imgs = [make_frame(k) for k in range(4)]
    lat = []
    start = time.monotonic()
    for i in range(1, n + 1):
        due = start + i / RATE
        d = due - time.monotonic()
        if d > 0:
            time.sleep(d)
        stamp = time.time()
        net(imgs[i % 4])
        lat.append((time.time() - stamp) * 1e3)
    steady = np.array(lat[min(50, n // 2):])
    return {"cuda": net.cuda, "device": net.device, "ready_s": ready,
            "latency_p50_ms": float(np.percentile(steady, 50)), "latency_p99_ms": float(np.percentile(steady, 99))}


if __name__ == "__main__":
    print("INPROC " + json.dumps(in_process()), flush=True)
