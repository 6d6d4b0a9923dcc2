"""A PyTorch reference of the tiny tokenizer, for the side-by-side benchmark.

It is written the way a PyTorch user would write the same model: the same layers and weights,
with PyTorch's own ops where they exist (`grid_sample` for the fusion's bilinear reads and the
renderer's trilinear reads, `scaled_dot_product_attention`, `F.gelu`). It reads what
`vs_pytorch dump DIR` wrote (our weights as safetensors, the encoder's input arrays, the rays and
our outputs), checks that its outputs match ours, and only then times each stage: eagerly on 1
and 2 threads, and under `torch.compile` on 2 threads. The world model's network
(`world_model.py`) is checked and timed beside them. Results go to `DIR/torch.json`.

    python bench/pytorch/tokenizer.py out/vs-pytorch [--no-compile]

Every layout below follows the Rust code it mirrors (file named in each docstring); burn's
`Linear` stores its weight as [in, out], so the weights are transposed once at load.
"""

import json
import math
import os
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F
from safetensors.torch import load_file

MASKED = -1e9  # nodes/blocks/src/attention.rs


def load_weights(path):
    """Our safetensors export, with every linear weight turned to PyTorch's [out, in]."""
    raw = load_file(path)
    weights = {}
    for name, value in raw.items():
        if name.endswith(".weight") and value.dim() == 2:
            value = value.t()
        weights[name] = value.contiguous()
    return weights


class Tokenizer:
    def __init__(self, weights, model):
        self.w = weights
        self.m = model
        self.cache = {}

    # --- layers -------------------------------------------------------------------------------
    def linear(self, x, name, bias=True):
        return F.linear(x, self.w[name + ".weight"], self.w.get(name + ".bias") if bias else None)

    def layer_norm(self, x, name, eps=1e-5):
        return F.layer_norm(x, (x.shape[-1],), self.w[name + ".gamma"], self.w[name + ".beta"], eps)

    def conv(self, x, name, stride=1, padding=0):
        return F.conv2d(x, self.w[name + ".weight"], self.w[name + ".bias"], stride, padding)

    # --- Swin (nodes/blocks/src/swin) -----------------------------------------------------------
    def relative_index(self, configured, tokens):
        key = ("index", configured, tokens)
        if key not in self.cache:
            side = int(round(math.sqrt(tokens)))
            span = 2 * configured - 1
            ys, xs = torch.meshgrid(torch.arange(side), torch.arange(side), indexing="ij")
            ys, xs = ys.reshape(-1), xs.reshape(-1)
            dy = ys[:, None] - ys[None, :] + configured - 1
            dx = xs[:, None] - xs[None, :] + configured - 1
            self.cache[key] = (dy * span + dx).reshape(-1)
        return self.cache[key]

    def shift_mask(self, height, width, window, shift):
        key = ("mask", height, width, window, shift)
        if key not in self.cache:
            def region(i, n):
                return 0 if i < n - window else (1 if i < n - shift else 2)

            labels = torch.zeros(height, width, dtype=torch.int64)
            for y in range(height):
                for x in range(width):
                    labels[y, x] = region(y, height) * 3 + region(x, width)
            windows = self.partition(labels[None, :, :, None], window)[..., 0]  # [nW, N]
            same = windows[:, :, None] == windows[:, None, :]
            self.cache[key] = torch.where(same, 0.0, MASKED)  # [nW, N, N]
        return self.cache[key]

    @staticmethod
    def partition(x, window):
        b, h, w, c = x.shape
        x = x.reshape(b, h // window, window, w // window, window, c).permute(0, 1, 3, 2, 4, 5)
        return x.reshape(-1, window * window, c)

    @staticmethod
    def reverse(windows, window, h, w):
        c = windows.shape[-1]
        b = windows.shape[0] // ((h // window) * (w // window))
        x = windows.reshape(b, h // window, w // window, window, window, c)
        return x.permute(0, 1, 3, 2, 4, 5).reshape(b, h, w, c)

    def window_attention(self, x, name, heads, configured, mask):
        count, tokens, dim = x.shape
        qkv = self.linear(x, name + ".qkv").reshape(count, tokens, 3, heads, dim // heads)
        q, k, v = qkv.permute(2, 0, 3, 1, 4).unbind(0)  # [B*, H, N, d] each
        table = self.w[name + ".bias_table"]
        bias = table[self.relative_index(configured, tokens)]  # [N * N, H]
        bias = bias.reshape(tokens, tokens, heads).permute(2, 0, 1)[None]  # [1, H, N, N]
        if mask is not None:
            windows = mask.shape[0]
            bias = (bias[:, None] + mask[None, :, None]).expand(count // windows, -1, -1, -1, -1)
            bias = bias.reshape(count, heads, tokens, tokens)
        out = F.scaled_dot_product_attention(q, k, v, attn_mask=bias)
        return self.linear(out.transpose(1, 2).reshape(count, tokens, dim), name + ".proj")

    def swin_block(self, x, name, heads, configured, shifted):
        b, h, w, c = x.shape
        smallest = min(h, w)
        if smallest <= configured:
            window, shift = smallest, 0
        else:
            window, shift = configured, (configured // 2 if shifted else 0)
        ph, pw = -(-h // window) * window, -(-w // window) * window
        y = self.layer_norm(x, name + ".norm1")
        if (ph, pw) != (h, w):
            y = F.pad(y, (0, 0, 0, pw - w, 0, ph - h))
        if shift:
            y = torch.roll(y, (-shift, -shift), (1, 2))
        mask = self.shift_mask(ph, pw, window, shift) if shift else None
        y = self.window_attention(self.partition(y, window), name + ".attention", heads, configured, mask)
        y = self.reverse(y, window, ph, pw)
        if shift:
            y = torch.roll(y, (shift, shift), (1, 2))
        y = y[:, :h, :w]
        x = x + y
        hidden = F.gelu(self.linear(self.layer_norm(x, name + ".norm2"), name + ".fc1"))
        return x + self.linear(hidden, name + ".fc2")

    @staticmethod
    def space_to_depth(x):
        b, h, w, c = x.shape
        x = x.reshape(b, h // 2, 2, w // 2, 2, c).permute(0, 1, 3, 4, 2, 5)
        return x.reshape(b, h // 2, w // 2, 4 * c)

    @staticmethod
    def depth_to_space(x):
        b, h, w, c4 = x.shape
        x = x.reshape(b, h, w, 2, 2, c4 // 4).permute(0, 1, 4, 2, 3, 5)
        return x.reshape(b, 2 * h, 2 * w, c4 // 4)

    def backbone(self, x, name, config, finer):
        """`SwinBackbone::forward_levels`: the last stage and the `finer` stages before it."""
        patch = config["patch"]
        y = self.conv(x, name + ".embed.proj", stride=patch).permute(0, 2, 3, 1)
        y = self.layer_norm(y, name + ".embed.norm")
        stages = len(config["depths"])
        first_kept = max(stages - (finer + 1), 0)
        levels = []
        for s, (depth, heads) in enumerate(zip(config["depths"], config["heads"])):
            for i in range(depth):
                y = self.swin_block(y, f"{name}.stages.{s}.blocks.{i}", heads, config["window"], i % 2 == 1)
            if s + 1 < stages:
                if s >= first_kept:
                    levels.append(y.permute(0, 3, 1, 2))
                merged = self.layer_norm(self.space_to_depth(y), f"{name}.stages.{s}.merge.norm")
                y = self.linear(merged, f"{name}.stages.{s}.merge.reduction", bias=False)
        return y.permute(0, 3, 1, 2), levels

    # --- encoder (nodes/tokenizer/src/encoder, model.rs) -----------------------------------------
    def encode(self, images, points, valid, cells, reference, reference_valid):
        m = self.m
        grid = m["bev"]["pillar_grid"]
        h = F.relu(self.layer_norm(self.linear(points, "pillar_net.linear"), "pillar_net.norm", 1e-3))
        pillars = (h * valid[..., None]).amax(1)  # [P, C]
        bev = torch.zeros(grid * grid, pillars.shape[1]).index_add_(0, cells, pillars)
        bev = bev.t().reshape(1, -1, grid, grid)
        lidar, _ = self.backbone(bev, "lidar_backbone", m["lidar_backbone"], 0)
        levels = max(m["fusion_levels"], 1)
        image_features, fine = self.backbone(images, "image_backbone", m["image_backbone"], levels - 1)
        fused = self.fusion(lidar, image_features, fine, reference, reference_valid)
        return self.conv(fused, "compress.proj")

    def fusion(self, bev, images, fine, reference, valid):
        """`DeformableFusion::forward`, with `grid_sample` for the bilinear reads."""
        _, dim, height, width = bev.shape
        cameras, _, fh, fw = images.shape
        k = self.m["fusion_heights"]
        queries = height * width
        query = bev.reshape(dim, queries).t()  # [Q, C]
        scale = torch.tensor([2.0 / fw, 2.0 / fh])
        offsets = self.linear(query, "fusion.offsets").reshape(queries, cameras, k, 2).transpose(0, 1)
        grid = (reference + offsets * scale).reshape(cameras, 1, queries * k, 2)
        valid_qck = valid.transpose(0, 1).reshape(queries, cameras * k)
        logits = self.linear(query, "fusion.weights") + (1.0 - valid_qck) * MASKED
        attention = (torch.softmax(logits, 1) * valid_qck).reshape(queries, cameras, k).transpose(0, 1)

        def sample(maps, projection):
            value = self.linear(maps.permute(0, 2, 3, 1), projection).permute(0, 3, 1, 2)
            out = F.grid_sample(value, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
            return out[:, :, 0].permute(0, 2, 1)  # [N_c, Q * K, C]

        sampled = sample(images, "fusion.value")
        for i, level in enumerate(fine):
            sampled = sampled + sample(level, f"fusion.fine_values.{i}")
        sampled = sampled.reshape(cameras, queries, k, dim)
        fused = (sampled * attention[..., None]).sum(2).sum(0)  # [Q, C]
        out = query + self.linear(fused, "fusion.output")
        return out.t().reshape(1, dim, height, width)

    # --- decoder (nodes/tokenizer/src/decoder/voxel_lift.rs) -----------------------------------
    def lift(self, latent):
        d = self.m["decoder"]
        x = self.linear(latent.permute(0, 2, 3, 1), "lift.input")
        for i in range(d["depths"][0]):
            x = self.swin_block(x, f"lift.before.{i}", d["heads"][0], d["window"], i % 2 == 1)
        x = self.layer_norm(self.depth_to_space(self.linear(x, "lift.expand.expand", bias=False)), "lift.expand.norm")
        for i in range(d["depths"][1]):
            x = self.swin_block(x, f"lift.after.{i}", d["heads"][1], d["window"], i % 2 == 1)
        x = self.linear(x, "lift.head")  # [1, Y, X, Z * C_v] (cell_split 1)
        return x.reshape(-1, d["voxel_channels"])  # the table, one row per voxel

    # --- rendering (nodes/tokenizer/src/render) -------------------------------------------------
    def voxel_grid(self, table):
        """The table as grid_sample's `[1, C_v, Z, Y, X]` volume."""
        d = self.m["decoder"]
        assert d["cell_split"] == 1, "the reference renders fields of cell_split 1"
        z, c = d["voxel_height"], d["voxel_channels"]
        side = int(round(math.sqrt(table.shape[0] // z)))
        return table.reshape(side, side, z, c).permute(3, 2, 0, 1)[None].contiguous()

    def render(self, grid, origins, directions, depths, vmin, vsize, chunk):
        """Dense volume rendering of every ray in chunks: expected depth, feature and opacity."""
        _, _, z, y, x = grid.shape
        size = torch.tensor([x, y, z], dtype=torch.float32)
        out_depth, out_feature, out_opacity = [], [], []
        for start in range(0, origins.shape[0], chunk):
            o = origins[start:start + chunk]
            d = directions[start:start + chunk]
            points = o[:, None, :] + depths[None, :, None] * d[:, None, :]  # [R, S, 3] ego
            voxel = (points - vmin) / vsize - 0.5  # voxel units, centre of voxel i at i
            normalised = 2.0 * voxel / (size - 1.0) - 1.0  # align_corners=True
            features = F.grid_sample(grid, normalised[None, None], mode="bilinear",
                                     padding_mode="zeros", align_corners=True)
            features = features[0, :, 0].permute(1, 2, 0)  # [R, S, C_v]
            logits = self.linear(F.relu(self.linear(features, "alpha_hidden")), "alpha_out")[..., 0]
            transparency = F.logsigmoid(-logits)
            weights = torch.exp(F.logsigmoid(logits) + torch.cumsum(transparency, 1) - transparency)
            out_depth.append((weights * depths).sum(1))
            out_feature.append(torch.bmm(weights[:, None, :], features)[:, 0])
            out_opacity.append(weights.sum(1))
        return torch.cat(out_depth), torch.cat(out_feature), torch.cat(out_opacity)

    def upsample_rgb(self, features, cameras, rows, columns):
        """`RgbUpsampler::forward`."""
        x = features.reshape(cameras, rows, columns, -1).permute(0, 3, 1, 2)
        x = F.relu(self.conv(x, "upsampler.input", padding=1))
        step = 0
        while f"upsampler.steps.{step}.weight" in self.w:
            x = F.interpolate(x, scale_factor=2, mode="nearest")
            x = F.relu(self.conv(x, f"upsampler.steps.{step}", padding=1))
            step += 1
        return torch.sigmoid(self.conv(x, "upsampler.to_rgb", padding=1))


def load(folder, name):
    return torch.from_numpy(np.load(os.path.join(folder, name + ".npy")))


def median_ms(function, runs):
    function()
    times = []
    for _ in range(runs):
        started = time.perf_counter()
        function()
        times.append((time.perf_counter() - started) * 1e3)
    return float(np.median(times))


def matmul_gflops(n=512, reps=5):
    a, b = torch.randn(n, n), torch.randn(n, n)
    a @ b
    best = math.inf
    for _ in range(reps):
        started = time.perf_counter()
        a @ b
        best = min(best, time.perf_counter() - started)
    return 2 * n ** 3 / best / 1e9


def main():
    folder = sys.argv[1]
    compile_too = "--no-compile" not in sys.argv
    meta = json.load(open(os.path.join(folder, "meta.json")))
    model = Tokenizer(load_weights(os.path.join(folder, "weights.safetensors")), meta["model"])
    inputs = dict(
        images=load(folder, "images"),
        points=load(folder, "pillar_points"),
        valid=load(folder, "pillar_valid"),
        cells=load(folder, "pillar_cells").long(),
        reference=load(folder, "reference"),
        reference_valid=load(folder, "reference_valid"),
    )
    rays = {name: load(folder, name) for name in
            ("camera_origins", "camera_directions", "lidar_origins", "lidar_directions")}
    depths = load(folder, "depths")
    vmin = torch.tensor(meta["voxel_min"])
    vsize = torch.tensor(meta["voxel_size"])
    chunk = meta["chunk"]
    cameras, rows, columns = meta["ray_grid"]
    ours = {name: load(folder, name) for name in
            ("latent", "voxel_table", "rgb", "lidar_depth", "camera_opacity")}

    def stages(tokenizer, encode, lift, render):
        def encoder():
            return encode(**inputs)

        def lifted():
            return lift(ours["latent"])

        def rendered():
            grid = tokenizer.voxel_grid(ours["voxel_table"])
            _, camera_features, _ = render(grid, rays["camera_origins"], rays["camera_directions"],
                                           depths, vmin, vsize, chunk)
            rgb = tokenizer.upsample_rgb(camera_features, cameras, rows, columns)
            lidar_depth, _, _ = render(grid, rays["lidar_origins"], rays["lidar_directions"],
                                       depths, vmin, vsize, chunk)
            return rgb, lidar_depth

        return encoder, lifted, rendered

    torch.set_num_threads(2)
    with torch.inference_mode():
        encoder, lifted, rendered = stages(model, model.encode, model.lift, model.render)
        latent = encoder()
        table = lifted()
        rgb, lidar_depth = rendered()
    agreement = {
        "latent_max_abs": float((latent - ours["latent"]).abs().max()),
        "voxel_table_max_abs": float((table - ours["voxel_table"]).abs().max()),
        "rgb_max_abs": float((rgb - ours["rgb"]).abs().max()),
        "rgb_8bit_levels_differing": int(
            ((rgb * 255).round() != (ours["rgb"] * 255).round()).sum()),
        "lidar_depth_max_abs_m": float((lidar_depth - ours["lidar_depth"]).abs().max()),
    }
    import world_model

    world, world_inputs, world_ours = world_model.load(folder)
    with torch.inference_mode():
        agreement["world_model_max_abs"] = float(
            (world.forward(**world_inputs) - world_ours).abs().max())
    print("agreement with ours:", json.dumps(agreement))
    tolerances = {"latent_max_abs": 1e-3, "voxel_table_max_abs": 1e-3, "rgb_max_abs": 1e-3,
                  "lidar_depth_max_abs_m": 1e-2, "world_model_max_abs": 1e-3}
    failed = [k for k, bound in tolerances.items() if not agreement[k] <= bound]
    if failed:
        sys.exit(f"the reference disagrees with ours beyond tolerance: {failed}; nothing timed")

    result = {
        "torch_version": torch.__version__,
        "build": f"{torch.get_num_interop_threads()} inter-op threads, MKL-DNN "
                 f"{'on' if torch.backends.mkldnn.is_available() else 'off'}",
        "allocator": os.environ.get("BEVWORLD_TORCH_ALLOCATOR", "glibc malloc, defaults"),
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "agreement": agreement,
        "eager": {},
    }
    runs = 10
    with torch.inference_mode():
        for threads in (1, 2):
            torch.set_num_threads(threads)
            result["eager"][str(threads)] = {
                "encoder_ms": median_ms(encoder, runs),
                "lift_ms": median_ms(lifted, runs),
                "render_dense_ms": median_ms(rendered, 5),
                "world_model_ms": median_ms(lambda: world.forward(**world_inputs), 5),
                "matmul_gflops": matmul_gflops(),
            }
            print(f"eager, {threads} thread(s):", json.dumps(result["eager"][str(threads)]))
        if compile_too:
            torch.set_num_threads(2)
            try:
                started = time.perf_counter()
                c_encoder, c_lifted, c_rendered = stages(
                    model, torch.compile(model.encode), torch.compile(model.lift),
                    torch.compile(model.render))
                c_world = torch.compile(world.forward)
                c_encoder(), c_lifted(), c_rendered(), c_world(**world_inputs)
                compile_s = time.perf_counter() - started
                result["compiled"] = {"2": {
                    "encoder_ms": median_ms(c_encoder, runs),
                    "lift_ms": median_ms(c_lifted, runs),
                    "render_dense_ms": median_ms(c_rendered, 5),
                    "world_model_ms": median_ms(lambda: c_world(**world_inputs), 5),
                    "compile_s": compile_s,
                }}
                print("torch.compile, 2 threads:", json.dumps(result["compiled"]["2"]))
            except Exception as error:  # noqa: BLE001 - any failure: report it, keep eager
                result["compile_error"] = f"{type(error).__name__}: {error}"[:400]
                print("torch.compile failed:", result["compile_error"])
    json.dump(result, open(os.path.join(folder, "torch.json"), "w"), indent=2)
    print("wrote", os.path.join(folder, "torch.json"))


if __name__ == "__main__":
    main()
