"""A PyTorch reference of the tiny world model's network (one pass over 3 condition frames and
6 future frames), for the side-by-side benchmark. Layouts follow nodes/world_model/src
(model.rs, block.rs, condition.rs, patch.rs) and nodes/blocks/src/adaln.rs; the fixed
encodings (2D token positions, 1D frame positions, the timestep's sines) are inputs, written by
`vs_pytorch dump` with the other arrays, because they are constants, not the network's cost.

    python bench/pytorch/world_model.py DIR   (imported by tokenizer.py, which times it)
"""

import json
import os

import numpy as np
import torch
import torch.nn.functional as F

from tokenizer import MASKED, load_weights

NORM_EPSILON = 1e-6  # nodes/world_model/src/block.rs, DiT's


class WorldModel:
    def __init__(self, weights, config):
        self.w = weights
        self.c = config

    def linear(self, x, name):
        return F.linear(x, self.w[name + ".weight"], self.w.get(name + ".bias"))

    @staticmethod
    def modulate(x, shift, scale):
        return x + x * scale + shift

    @staticmethod
    def norm(x):
        return F.layer_norm(x, (x.shape[-1],), eps=NORM_EPSILON)

    def attention(self, x, name, mask):
        count, tokens, dim = x.shape
        heads = self.c["heads"]
        qkv = self.linear(x, name + ".qkv").reshape(count, tokens, 3, heads, dim // heads)
        q, k, v = qkv.permute(2, 0, 3, 1, 4).unbind(0)
        out = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
        return self.linear(out.transpose(1, 2).reshape(count, tokens, dim), name + ".proj")

    def forward(self, latents, actions, time_embedding, space, time, future, warped=None):
        c = self.c
        b, frames, channels, height, width = latents.shape
        p = c["patch"]
        rows, columns = height // p, width // p

        def patchify(x):
            n = x.shape[1]
            x = x.reshape(b, n, channels, rows, p, columns, p)
            return x.permute(0, 1, 3, 5, 2, 4, 6).reshape(b, n, rows * columns, -1)

        x = self.linear(patchify(latents), "patch_embed") + space[None, None] + time[None, :, None]
        if warped is not None and "warp_embed.weight" in self.w:
            # ego_warp_input: the future frames' tokens also embed their ego-warped latent.
            w = self.linear(patchify(warped), "warp_embed")
            x = torch.cat([x[:, : frames - future], x[:, frames - future :] + w], 1)
        action = self.linear(F.silu(self.linear(actions, "condition.action_in")), "condition.action_out")
        timestep = self.linear(F.silu(self.linear(time_embedding, "condition.time_in")), "condition.time_out")
        condition = torch.cat([action, timestep.reshape(b, frames, -1)], 2)  # [B, F, c]
        causal = torch.full((frames, frames), MASKED).triu(1)  # 0 on and below the diagonal
        d = x.shape[-1]
        length = rows * columns
        for i in range(c["depth"]):
            name = f"blocks.{i}"
            m = [v.unsqueeze(2) for v in self.linear(F.silu(condition), name + ".modulation.linear").chunk(9, -1)]
            h = self.modulate(self.norm(x), m[0], m[1]).transpose(1, 2).reshape(b * length, frames, d)
            h = self.attention(h, name + ".temporal", causal)
            x = x + m[2] * h.reshape(b, length, frames, d).transpose(1, 2)
            h = self.modulate(self.norm(x), m[3], m[4]).reshape(b * frames, length, d)
            x = x + m[5] * self.attention(h, name + ".spatial", None).reshape(b, frames, length, d)
            h = self.modulate(self.norm(x), m[6], m[7])
            h = self.linear(F.gelu(self.linear(h, name + ".mlp.fc1")), name + ".mlp.fc2")
            x = x + m[8] * h
        x, condition = x[:, frames - future:], condition[:, frames - future:]
        m = [v.unsqueeze(2) for v in self.linear(F.silu(condition), "final_modulation.linear").chunk(2, -1)]
        out = self.linear(self.modulate(self.norm(x), m[0], m[1]), "head")
        out = out.reshape(b, future, rows, columns, channels, p, p).permute(0, 1, 4, 2, 5, 3, 6)
        return out.reshape(b, future, channels, height, width)


def load(folder):
    """The model, its inputs and our output, from what `vs_pytorch dump` wrote."""
    meta = json.load(open(os.path.join(folder, "world_model.json")))
    model = WorldModel(load_weights(os.path.join(folder, "world_model.safetensors")), meta["config"])

    def array(name):
        return torch.from_numpy(np.load(os.path.join(folder, name + ".npy")))

    inputs = dict(
        latents=array("wm_latents"),
        actions=array("wm_actions"),
        time_embedding=array("wm_time_embedding"),
        space=array("wm_space"),
        time=array("wm_time"),
        future=meta["future"],
        warped=array("wm_warped"),
    )
    return model, inputs, array("wm_output")
