"""An experiment, not part of the project: would `learned-mixture` gain from features computed at
coarse scales (a small U-Net encoder), a pyramid of predicted kernels (Bálint et al. 2023), or a
U-Net that reconstructs the image from the 1-spp colour and the guides and corrects the mixture's
output (``--reconstruct``)?

The network is written in PyTorch so that variants train in minutes; it reads the inputs that
``python -m denoise.train --method learned-mixture`` keeps in ``WORK/mixture-inputs`` (the method's
own images and features) and trains on the same crops, flips, exposures and loss (each crop's
relMSE over asvgf's) with the same held-out split. The results and what they say are in
docs/learned_mixture.md ("A network with coarse-scale features, measured" and "A reconstruction
from the 1-spp colour, measured").

    # with the project's .venv: the G-buffers of the training and benchmark sequences, and the
    # benchmark sequences' inputs (against their reference)
    .venv/bin/python docs/experiments/coarse_scale_network.py gbuffers OUT/gbuffers WORK/*[!e]
    .venv/bin/python docs/experiments/coarse_scale_network.py inputs OUT/bench-inputs out/denoise/SEQ_...
    # with the project's .venv: the speed of the method's convolution and of dr.matmul at 1280×720
    .venv/bin/python docs/experiments/coarse_scale_network.py speed
    # with a Python that has torch and numpy (python3 -m venv /tmp/torchenv; pip install torch numpy)
    python coarse_scale_network.py train TAG --work WORK --gbuffers OUT/gbuffers [--encoder] [--pyramid] ...
    python coarse_scale_network.py train TAG --work WORK --gbuffers OUT/gbuffers --reconstruct 16 32 48 64 \
        --coarse 1 --leaky --bound 1 --robust --start denoise/learned_mixture.json --rate 0.001
    python coarse_scale_network.py train control --work WORK --start denoise/learned_mixture.json --rate 0.001
    python coarse_scale_network.py judge TAG... denoise/learned_mixture.json --bench OUT/bench-inputs \
        --bench-json BENCH.json [--gbuffers OUT/gbuffers --bench-gbuffers OUT/bench-gbuffers]
(``TORCH_THREADS``: torch's threads, 1 by default.)
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

#: learned-mixture's images, in its order, and the six that asvgf makes at its fitted σ alone
CANDIDATES = ("slow", *(f"{level}_{s}" for s in ("half", "one", "double") for level in ("a1", "a2", "a3", "wide")),
              "asvgf")
AT_FITTED_SIGMA = ("slow", "a1_one", "a2_one", "a3_one", "wide_one", "asvgf")
#: learned-mixture's held-out sequences, crops, batch, exposure range, relMSE's ε and first loss frame
HELD_OUT = ("mirrors_switch", "showcase_disocclusion", "bunny_dolly")
CROP, BATCH, EXPOSURE, EPSILON, LOSS_FROM, JUDGED_FROM = 64, 8, (0.5, 2.0), 1e-2, 1, 4
#: statistics that come before the ratios in the inputs
STATISTICS = 7
#: the reconstruction's guides (``--reconstruct``), from the gbuffers mode's files
GUIDES = ("color", "albedo", "normal")


def project_mode(mode: str, out: Path, folders: list[Path]) -> None:
    """The G-buffers (``gbuffers``) or the method's inputs (``inputs``) of exported folders, one .npz each."""
    import mitsuba as mi  # noqa: PLC0415  the project's modes only; the torch modes run without Mitsuba

    mi.set_variant("llvm_ad_rgb")
    from denoise.mixture_training import compute_inputs  # noqa: PLC0415  after the variant
    from denoise.training import load_sequence  # noqa: PLC0415  after the variant

    out.mkdir(parents=True, exist_ok=True)
    for folder in folders:
        path = out / f"{folder.name.split('_320x180')[0]}.npz"
        if path.exists():
            continue
        if mode == "inputs":
            np.savez(path, **compute_inputs(folder))
        else:
            frames = load_sequence(folder)
            albedo = np.stack([f.albedo if f.albedo is not None else np.ones_like(f.color) for f in frames])
            normal = np.nan_to_num(np.stack([f.normal for f in frames]), nan=0, posinf=0, neginf=0)
            color = np.nan_to_num(np.stack([f.color for f in frames]), nan=0, posinf=0, neginf=0)
            np.savez(path, albedo=albedo.astype(np.float32), normal=normal.astype(np.float32),
                     color=color.astype(np.float32))
        print(path, flush=True)


def convolution_speed() -> None:
    """Multiply-adds a second at 1280×720 of learned-mixture's Dr.Jit 3×3 convolution, and of
    ``dr.matmul`` and NumPy on an im2col's matrices (9 × 32 columns by 24)."""
    import drjit as dr  # noqa: PLC0415  as in project_mode
    import mitsuba as mi  # noqa: PLC0415

    mi.set_variant("llvm_ad_rgb")
    from denoise.methods.learned_mixture import Taps, convolution  # noqa: PLC0415  after the variant

    width, height, rng = 1280, 720, np.random.default_rng(0)

    def best(run, repeats=4):
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            run()
            dr.sync_thread()
            times.append(time.perf_counter() - start)
        return min(times)

    for cin, cout in ((20, 8), (8, 8), (32, 24), (56, 24)):
        channels = [mi.Float(rng.random(width * height).astype(np.float32)) for _ in range(cin)]
        weights, taps = (rng.standard_normal((cout, cin, 3, 3)) * 0.1).tolist(), Taps(width, height)
        dr.eval(channels)
        t = best(lambda: convolution(channels, weights, [0.0] * cout, taps))  # noqa: B023  run at once
        print(f"convolution {cin}->{cout}: {t * 1e3:.0f} ms, {cin * cout * 9 * width * height / t / 1e9:.1f} G/s")
    n, k, m = width * height, 9 * 32, 24
    a, b = rng.random((n, k)).astype(np.float32), rng.random((k, m)).astype(np.float32)
    ta, tb = mi.TensorXf(a), mi.TensorXf(b)
    dr.eval(ta, tb)
    t = best(lambda: dr.eval(dr.matmul(ta, tb)))
    print(f"dr.matmul {n}x{k} by {k}x{m}: {t * 1e3:.0f} ms, {n * k * m / t / 1e9:.1f} G/s")
    t = best(lambda: a @ b)
    print(f"numpy {n}x{k} by {k}x{m}: {t * 1e3:.0f} ms, {n * k * m / t / 1e9:.1f} G/s")


def torch_modes(argv: list[str]) -> None:
    import torch  # noqa: PLC0415  not a dependency of the project
    import torch.nn.functional as F  # noqa: N812, PLC0415
    from torch import nn  # noqa: PLC0415

    torch.set_num_threads(int(os.environ.get("TORCH_THREADS", "1")))  # 1: beside a render, two would wait

    def luminance(image):  # (..., 3, H, W)
        return 0.2126 * image[..., 0, :, :] + 0.7152 * image[..., 1, :, :] + 0.0722 * image[..., 2, :, :]

    def load(path: Path, gbuffers: Path | None, kept: list[int], guides: Path | None = None) -> dict:
        data = np.load(path)
        x = torch.from_numpy(data["x"])[:, list(range(STATISTICS)) + [STATISTICS + i - 1 for i in kept if i]]
        images = torch.from_numpy(data["images"]).permute(0, 1, 4, 2, 3)
        base = images[:, CANDIDATES.index("asvgf")].contiguous()
        images = images[:, kept].contiguous()
        if gbuffers is not None:
            g = np.load(gbuffers / path.name)
            albedo = torch.from_numpy(g["albedo"]).permute(0, 3, 1, 2)
            shown = torch.from_numpy(g["color"]).permute(0, 3, 1, 2) * albedo
            x = torch.cat([x, albedo, torch.from_numpy(g["normal"]).permute(0, 3, 1, 2),
                           torch.log1p(luminance(shown).clamp(min=0)).unsqueeze(1),
                           torch.log1p(luminance(images[:, 0]).clamp(min=0)).unsqueeze(1)], 1)
        out = {"x": x.contiguous(), "images": images,
               "target": torch.from_numpy(data["target"]).permute(0, 3, 1, 2).contiguous(), "asvgf": base}
        if guides is not None:  # the reconstruction's: the 1-spp demodulated colour, the albedo and the normal
            g = np.load(guides / path.name)
            out.update({k: torch.from_numpy(g[k]).permute(0, 3, 1, 2).contiguous() for k in GUIDES})
        return out

    def conv(cin, cout):
        return nn.Conv2d(cin, cout, 3, padding=1, padding_mode="replicate")

    def zero_layer(cin, cout, biases):
        layer = nn.Conv2d(cin, cout, 1)
        nn.init.zeros_(layer.weight)
        with torch.no_grad():
            layer.bias.copy_(torch.tensor(biases, dtype=torch.float32))
        return layer

    def kernel(image, logits):
        """A predicted 3×3 kernel (a softmax of 9 logits a pixel) over ``image``, the border repeated."""
        weights, padded = torch.softmax(logits, 1), F.pad(image, (1, 1, 1, 1), mode="replicate")
        h, w = image.shape[-2:]
        taps = torch.stack([padded[..., dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)], 1)
        return (weights.unsqueeze(2) * taps).sum(1)

    def up(t, size):
        return F.interpolate(t, size=size, mode="bilinear", align_corners=False)

    class Network(nn.Module):
        """learned-mixture's network (two 3×3 layers, a softmax blend, a predicted 3×3 kernel), with,
        optionally, an encoder at ½, ¼ and ⅛ scale whose decoder's features join the last layer
        (``encoder``), and kernels predicted at ½ and ¼ scale whose filtered blends replace the
        finer level's low frequencies by a predicted amount (``pyramid``)."""

        def __init__(self, inputs, images, channels=8, encoder=False, pyramid=False, width=16, reconstruct=(),
                     coarse=False, leaky=False, bound=3.0):
            super().__init__()
            self.bound = bound  # the correction's factor stays within exp(±bound)
            self.act = (lambda t: F.leaky_relu(t, 0.1)) if leaky else F.relu  # the U-Net's activation
            self.coarse = int(coarse)  # the reconstruction this many scales down: its correction upsampled
            self.encoder, self.pyramid, self.images, self.reconstruct = encoder, pyramid, images, tuple(reconstruct)
            if reconstruct:  # full size, ½, ¼, ⅛: two 3×3 layers at ⅛, one on the way down and up elsewhere
                w0, w1, w2, w3 = reconstruct
                self.r0, self.r1, self.r2 = conv(inputs + 12, w0), conv(w0, w1), conv(w1, w2)
                self.r3, self.r3b = conv(w2, w3), conv(w3, w3)
                self.u2, self.u1, self.u0 = conv(w3 + w2, w2), conv(w2 + w1, w1), conv(w1 + w0, w0)
                self.rout = zero_layer(w0, 3, [0.0, 0.0, 0.0])
            self.c1, self.c2 = conv(inputs, channels), conv(channels, channels)
            if encoder:
                self.e1, self.e2, self.e3 = conv(inputs, width), conv(width, width), conv(width, width)
                self.d2, self.d1 = conv(2 * width, width), conv(2 * width, width)
            start = [0.0] * images + [0.0] * 9 + ([-2.0] if pyramid else [])
            start[images - 1], start[images + 4] = 4.0, 5.0  # learned-mixture's start: near asvgf, the identity
            self.head = zero_layer(channels + width * encoder, len(start), start)
            if pyramid:
                self.k1 = zero_layer(width, 10, [0, 0, 0, 0, 5.0, 0, 0, 0, 0, -2.0])
                self.k2 = zero_layer(width, 9, [0, 0, 0, 0, 5.0, 0, 0, 0, 0])

        def forward(self, x, images, guides=None):
            size = x.shape[-2:]
            if self.reconstruct:
                g0 = self.mixture(x, images)
                color, albedo, normal = guides
                rin = torch.cat([x, torch.log1p(g0.clamp(min=0)), torch.log1p(color.clamp(min=0)), albedo, normal], 1)
                r0 = self.act(self.r0(F.avg_pool2d(rin, 2 ** self.coarse) if self.coarse else rin))
                r1 = self.act(self.r1(F.avg_pool2d(r0, 2)))
                r2 = self.act(self.r2(F.avg_pool2d(r1, 2)))
                r3 = self.act(self.r3b(self.act(self.r3(F.avg_pool2d(r2, 2)))))
                u2 = self.act(self.u2(torch.cat([up(r3, r2.shape[-2:]), r2], 1)))
                u1 = self.act(self.u1(torch.cat([up(u2, r1.shape[-2:]), r1], 1)))
                u0 = self.act(self.u0(torch.cat([up(u1, r0.shape[-2:]), r0], 1)))
                correction = self.rout(u0)
                if self.coarse:
                    correction = up(correction, size)
                return g0 * torch.exp(self.bound * torch.tanh(correction / self.bound))
            return self.mixture(x, images)

        def macs(self):
            """Multiply-adds a pixel of the reconstruction's layers (the mixture's: about 2.2k)."""
            if not self.reconstruct:
                return 0
            scale = {"r0": 1, "u0": 1, "r1": 4, "u1": 4, "r2": 16, "u2": 16, "r3": 64, "r3b": 64, "rout": 1}
            return sum(getattr(self, n).weight.numel() / scale[n] for n in scale) / 4 ** self.coarse

        def mixture(self, x, images):
            size = x.shape[-2:]
            h = F.relu(self.c2(F.relu(self.c1(x))))
            if self.encoder:
                e1 = F.relu(self.e1(F.avg_pool2d(x, 2)))
                e2 = F.relu(self.e2(F.avg_pool2d(e1, 2)))
                e3 = F.relu(self.e3(F.avg_pool2d(e2, 2)))
                d2 = F.relu(self.d2(torch.cat([up(e3, e2.shape[-2:]), e2], 1)))
                d1 = F.relu(self.d1(torch.cat([up(d2, e1.shape[-2:]), e1], 1)))
                h = torch.cat([h, up(d1, size)], 1)
            o, k = self.head(h), self.images
            blend = (torch.softmax(o[:, :k], 1).unsqueeze(2) * images).sum(1)
            g0 = kernel(blend, o[:, k:k + 9])
            if not self.pyramid:
                return g0
            b1 = F.avg_pool2d(blend, 2)
            f2 = kernel(F.avg_pool2d(b1, 2), self.k2(d2))
            q1 = self.k1(d1)
            g1 = kernel(b1, q1[:, :9])
            f1 = g1 + torch.sigmoid(q1[:, 9:]) * (up(f2, g1.shape[-2:]) - up(F.avg_pool2d(g1, 2), g1.shape[-2:]))
            return g0 + torch.sigmoid(o[:, k + 9:]) * (up(f1, size) - up(F.avg_pool2d(g0, 2), size))

    def whole(net, x, images, guides=None):
        """The network on whole frames, padded to a multiple of 8 (the encoder's three halvings)."""
        h, w = x.shape[-2:]
        multiple = 8 * 2 ** net.coarse
        ph, pw = (-h) % multiple, (-w) % multiple
        x = F.pad(x, (0, pw, 0, ph), mode="replicate")
        b, k = images.shape[:2]
        images = F.pad(images.reshape(b, k * 3, h, w), (0, pw, 0, ph), mode="replicate")
        if guides is not None:
            guides = [F.pad(g, (0, pw, 0, ph), mode="replicate") for g in guides]
        return net(x, images.reshape(b, k, 3, h + ph, w + pw), guides)[..., :h, :w]

    def relmse(o, t):
        return float(((o - t) ** 2 / (t ** 2 + EPSILON)).mean())

    def errors(net, data, first):
        """Mean relMSE of the network's and asvgf's outputs over frames ``first`` on."""
        with torch.no_grad():
            frames = range(first, data["x"].shape[0])
            ours = [relmse(whole(net, data["x"][f:f + 1], data["images"][f:f + 1],
                                 [data[k][f:f + 1] for k in GUIDES] if "color" in data else None)[0], data["target"][f])
                    for f in frames]
            return float(np.mean(ours)), float(np.mean([relmse(data["asvgf"][f], data["target"][f]) for f in frames]))

    def committed(path: Path):
        """A learned-mixture weights file as a :class:`Network` (its layout is torch's: out, in, y, x)."""
        w = json.loads(path.read_text())
        channels, inputs = w["channels"], len(w["features"])
        net = Network(inputs, len(CANDIDATES), channels)

        def t(name):
            return torch.tensor(np.array(w[name], np.float32))
        with torch.no_grad():
            net.c1.weight.copy_(t("w1").reshape(channels, inputs, 3, 3))
            net.c1.bias.copy_(t("b1"))
            net.c2.weight.copy_(t("w2").reshape(channels, channels, 3, 3))
            net.c2.bias.copy_(t("b2"))
            head = torch.cat([t("w3").reshape(-1, channels), t("w4").reshape(9, channels)])
            net.head.weight.copy_(head[..., None, None])
            net.head.bias.copy_(torch.cat([t("b3"), t("b4")]))
        return net, {"gbuffers": None, "kept": list(range(len(CANDIDATES)))}

    parser = argparse.ArgumentParser(prog="coarse_scale_network.py")
    parser.add_argument("mode", choices=("train", "judge"))
    parser.add_argument("tags", nargs="+", help="a run's name (judge: or a learned-mixture weights file)")
    parser.add_argument("--work", type=Path, default=Path("out/train"), help="the training's --work")
    parser.add_argument("--gbuffers", type=Path, help="read the G-buffers too (the gbuffers mode's folder)")
    parser.add_argument("--bench-gbuffers", type=Path, help="the benchmark sequences' G-buffers")
    parser.add_argument("--encoder", action="store_true")
    parser.add_argument("--pyramid", action="store_true")
    parser.add_argument("--fitted-sigma-only", action="store_true", help=f"blend {len(AT_FITTED_SIGMA)} images")
    parser.add_argument("--width", type=int, default=16, help="the encoder's channels")
    parser.add_argument("--reconstruct", type=int, nargs=4, default=(), metavar="C",
                        help="a U-Net of these channels at full, ½, ¼, ⅛ size, on the 1-spp colour, the guides and the "
                             "mixture's output, correcting that output per pixel and channel (reads --gbuffers)")
    parser.add_argument("--leaky", action="store_true", help="the reconstruction's activation: leaky ReLU (0.1)")
    parser.add_argument("--bound", type=float, default=3.0, help="the correction within exp(±BOUND)")
    parser.add_argument("--robust", action="store_true",
                        help="clip each step's gradient norm to 1 and keep the weights of the best held-out loss")
    parser.add_argument("--coarse", type=int, default=0, metavar="K",
                        help="the reconstruction K halvings down (1: at ½, ¼, ⅛, ¹⁄₁₆ size)")
    parser.add_argument("--steps", type=int, default=6000)
    parser.add_argument("--start", type=Path, help="start the mixture's layers from this learned-mixture file")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rate", type=float, default=0.003)
    parser.add_argument("--runs", type=Path, default=Path("out/coarse_scale_network"))
    parser.add_argument("--bench", type=Path, help="the benchmark sequences' inputs (the inputs mode's folder)")
    parser.add_argument("--bench-json", type=Path, help="benchmarks.denoise --json of the same sequences")
    a = parser.parse_args(argv)
    store = a.work / "mixture-inputs"
    if a.mode == "train":
        if a.pyramid and not a.encoder:
            parser.error("--pyramid predicts its kernels from the encoder's features: add --encoder")
        kept = [CANDIDATES.index(c) for c in (AT_FITTED_SIGMA if a.fitted_sigma_only else CANDIDATES)]
        paths = sorted(store.glob("*.npz"))
        if a.reconstruct and a.gbuffers is None:
            parser.error("--reconstruct reads the 1-spp colour and the guides: add --gbuffers")
        into_x, guides = (None, a.gbuffers) if a.reconstruct else (a.gbuffers, None)
        train = [load(p, into_x, kept, guides) for p in paths if p.stem not in HELD_OUT]
        held = [load(p, into_x, kept, guides) for p in paths if p.stem in HELD_OUT]
        torch.manual_seed(a.seed)
        net = Network(train[0]["x"].shape[1], len(kept), encoder=a.encoder, pyramid=a.pyramid, width=a.width,
                      reconstruct=a.reconstruct, coarse=a.coarse, leaky=a.leaky, bound=a.bound)
        if a.start is not None:  # the mixture's layers from a learned-mixture weights file
            net.load_state_dict(committed(a.start)[0].state_dict(), strict=False)
        print(f"{a.tags[0]}: the reconstruction's {net.macs():.0f} multiply-adds a pixel", file=sys.stderr)
        adam, rng, start, losses = torch.optim.Adam(net.parameters(), lr=a.rate), np.random.default_rng(a.seed), \
            time.time(), []
        best = (np.inf, None)
        for step in range(a.steps + 1):
            if step % 500 == 0 or step == a.steps:
                loss = np.mean([o / b for o, b in (errors(net, d, LOSS_FROM) for d in held)])
                if a.robust and loss < best[0]:
                    best = (loss, {k: v.clone() for k, v in net.state_dict().items()})
                print(f"{a.tags[0]} step {step}: held-out {loss:.4f}, training {np.mean(losses[-200:] or [np.nan]):.4f}"
                      f" ({time.time() - start:.0f} s)", file=sys.stderr, flush=True)
            if step == a.steps:
                break
            crops = []
            for _ in range(BATCH):
                d = train[int(rng.integers(len(train)))]
                frames, _, height, width = d["x"].shape
                f, y, x = int(rng.integers(LOSS_FROM, frames)), int(rng.integers(height - CROP + 1)), \
                    int(rng.integers(width - CROP + 1))
                keys = ("x", "images", "target", "asvgf") + (GUIDES if a.reconstruct else ())
                crop = [d[k][f, ..., y:y + CROP, x:x + CROP] for k in keys]
                for axis in (-1, -2):
                    if rng.integers(2):
                        crop = [c.flip(axis) for c in crop]
                exposure = float(np.exp(rng.uniform(*np.log(EXPOSURE))))
                if into_x is not None:  # the two log luminances follow the exposure
                    crop[0] = crop[0].clone()
                    crop[0][-2:] = torch.log1p(torch.expm1(crop[0][-2:]) * exposure)
                crops.append([crop[0]] + [c * exposure for c in crop[1:5]] + crop[5:])
            x, images, target, base, *guides = (torch.stack(c) for c in zip(*crops))
            per = ((net(x, images, guides or None) - target) ** 2 / (target ** 2 + EPSILON)).mean((1, 2, 3))
            loss = (per / ((base - target) ** 2 / (target ** 2 + EPSILON)).mean((1, 2, 3)).clamp(min=1e-12)).mean()
            adam.zero_grad()
            loss.backward()
            if a.robust:
                torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            adam.step()
            losses.append(loss.item())
        if a.robust:
            print(f"{a.tags[0]}: kept the best held-out loss, {best[0]:.4f}", file=sys.stderr)
            net.load_state_dict(best[1])
        a.runs.mkdir(parents=True, exist_ok=True)
        torch.save({"state": net.state_dict(), "inputs": train[0]["x"].shape[1], "kept": kept,
                    "reconstruct": list(a.reconstruct),
                    "settings": {k: str(v) for k, v in vars(a).items()}}, a.runs / f"{a.tags[0]}.pt")
        return
    high, noise = defaultdict(list), {}
    record = json.loads(a.bench_json.read_text())
    for r in record["results"]:
        if r["method"] == "oidn-high" and r["frame"] >= JUDGED_FROM:
            high[r["sequence"]].append(r["relmse"])
    noise = {s["name"]: s["reference_noise"] for s in record["sequences"]}
    for tag in a.tags:
        if tag.endswith(".json"):
            net, run = committed(Path(tag))
            run.update(guides=None, held_guides=None)
        else:
            saved = torch.load(a.runs / f"{tag}.pt", weights_only=False)
            s = saved["settings"]
            reconstruct = tuple(saved.get("reconstruct", ()))
            net = Network(saved["inputs"], len(saved["kept"]), encoder=s["encoder"] == "True",
                          pyramid=s["pyramid"] == "True", width=int(s["width"]), reconstruct=reconstruct,
                          coarse=int(s.get("coarse", "0")),
                          leaky=s.get("leaky") == "True", bound=float(s.get("bound", "3.0")))
            net.load_state_dict(saved["state"])
            run = {"gbuffers": a.bench_gbuffers if s["gbuffers"] != "None" and not reconstruct else None,
                   "kept": saved["kept"], "guides": a.bench_gbuffers if reconstruct else None,
                   "held_guides": a.gbuffers if reconstruct else None}
        held = np.mean([o / b for o, b in (errors(net, load(store / f"{n}.npz", None if run["gbuffers"] is None
                                                                else a.gbuffers, run["kept"], run["held_guides"]),
                                                  LOSS_FROM)
                                           for n in HELD_OUT)])
        row = [f"{Path(tag).name}: held-out {held:.3f}"]
        for name in sorted(high):
            o, b = errors(net, load(a.bench / f"{name}.npz", run["gbuffers"], run["kept"], run["guides"]), JUDGED_FROM)
            h, n = float(np.mean(high[name])), noise[name]
            row.append(f"{name} {o:.4f} ({o / b:.2f}x asvgf, {o / h:.2f}x high; less the reference's noise "
                       f"{(o - n) / (b - n):.2f}x, {(o - n) / (h - n):.2f}x)")
        print(" | ".join(row), flush=True)


if __name__ == "__main__":
    if sys.argv[1:] == ["speed"]:
        convolution_speed()
    elif len(sys.argv) > 2 and sys.argv[1] in ("gbuffers", "inputs"):
        project_mode(sys.argv[1], Path(sys.argv[2]), [Path(p) for p in sys.argv[3:]])
    else:
        torch_modes(sys.argv[1:])
