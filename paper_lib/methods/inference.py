"""Lean inference over all k members: the member network's numbers, less work.

The modules in layers.py run every member through every layer, as the training update needs
them (and training keeps using only them). Inference only needs the outputs, so this path
computes the same numbers with less work:
- the Nature CNN's conv1 (weights and input the same for every member) runs once, not on k
  copies of its input; an ensemble's conv1 runs all k kernels as one wider convolution of
  the one input; DropConnect's conv2 convolves a state once against its k masked kernels;
- on many states a Masksembles member computes only the units its mask keeps (member j's
  weights gathered as W[kept_out_j][:, kept_in_j], all members in one batched matmul or
  grouped convolution): for k = 4 at scale 2 about one dense network's multiply-adds instead
  of k networks'; the gathered weights and kept units are made once and reused across calls
  while the weights and masks stay the same (`derived`);
- MC masks per (member, state) come from `per_state` (exactly `per_state_masks`' draws);
- image batches run in chunks of states, so memory stays bounded for any batch;
- no module calls, no SB3 distribution objects, no repeated views: on one state, Python
  overhead is most of the cost.

Numbers: an MLP on fewer than COMPACT_MIN_STATES states gives the reference's bits (the same
tensor ops on the same shapes); Masksembles on kept units and the CNN agree up to float
rounding (~1e-7 relative). On many states there are two paths (`PATHS`): "exact", the numbers
every committed score was computed with, bit for bit; "fast" (states-major Masksembles towers,
tanh from numpy, features-major heads), the same up to float rounding in about half the time.
`members` falls back to the reference modules (`reference_members`) with autograd on or for a
network this path does not know. tests/methods/test_fast_inference.py and test_inference_paths.py
hold them all equal.
"""

from __future__ import annotations

import weakref
from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np
import torch as th
import torch.nn.functional as F
from stable_baselines3.common.preprocessing import preprocess_obs
from stable_baselines3.common.torch_layers import FlattenExtractor
from torch import nn

from paper_lib.methods import per_state
from paper_lib.methods.derived import derived
from paper_lib.methods.layers import (
    DROPCONNECT,
    ENSEMBLE,
    SHARED,
    MasksemblesMask,
    MCDropout,
    MemberConv2d,
    MemberLinear,
    is_stochastic,
    per_state_masks,
)
from paper_lib.methods.networks import MemberActorCritic, MemberMLP, MemberNatureCNN

#: From this many states on, a Masksembles member runs on its kept units only: the thin batched
#: matmuls of a few states cost more than the dense layers below ~32 states. Below it, the MLP path
#: is the reference's own arithmetic, so acting (`predict` on a few states) gives bit-identical actions
#: on either path.
COMPACT_MIN_STATES = 64
#: Image states per pass: the k members' activations of this many states stay a few tens of MB.
IMAGE_CHUNK_STATES = 64
#: Elementwise activations: applied to a member's kept units, they give its kept outputs.
ELEMENTWISE = frozenset((nn.Tanh, nn.ReLU, nn.LeakyReLU, nn.ELU, nn.SELU, nn.GELU, nn.SiLU, nn.Sigmoid, nn.Softplus,
                         nn.Identity))
#: Activations called as functions: a module call costs more than a small tensor op.
_FUNCTIONS = {nn.Tanh: th.tanh, nn.ReLU: th.relu, nn.Identity: lambda x: x}
#: The lean path's two ways on COMPACT_MIN_STATES states or more (below it both are the reference's arithmetic):
#: "exact" gives the numbers every committed score was computed with, bit for bit (scoring's default);
#: "fast" lays a Masksembles MLP out states-major (each member's kept units, first layer included) and takes
#: tanh from numpy (~12x faster than torch's on this CPU, within ~1 ulp): the same numbers up to float rounding.
PATHS = ("exact", "fast")


class Unsupported(Exception):
    """A network this path does not know; the caller runs the reference modules instead."""


def check_path(path: str) -> str:
    if path not in PATHS:
        raise ValueError(f"unknown inference path {path!r}; use one of {PATHS} ('exact': the committed scores' "
                         "numbers bit for bit, 'fast': the same up to float rounding)")
    return path


def fast_arithmetic(path: str, n_states: int) -> bool:
    """Whether a pass of `n_states` states on `path` may round differently from the exact path."""
    return check_path(path) == "fast" and n_states >= COMPACT_MIN_STATES


@dataclass
class Pass:
    """What one inference call shares across its chunks and layers."""

    k: int
    seeds: per_state.StateSeeds | None
    compact: bool  # Masksembles linear layers on kept units (many states)
    fast: bool = False  # the "fast" path (`PATHS`); only on many states

    def chunk(self, start: int, stop: int, n_states: int) -> Pass:
        if self.seeds is None or (start, stop) == (0, n_states):
            return self
        return Pass(self.k, self.seeds.chunk(start, stop), self.compact, self.fast)

    def layer_seeds(self, layer: nn.Module) -> list[int]:
        if self.seeds is None or id(layer) not in self.seeds.streams:
            raise Unsupported("a stochastic layer without per-state seeds")
        return self.seeds.for_layer(layer)


def activate(module: nn.Module, x: th.Tensor) -> th.Tensor:
    return _FUNCTIONS.get(type(module), module)(x)


def activate_owned(module: nn.Module, x: th.Tensor) -> th.Tensor:
    """The fast path's `activate` on a tensor this pass made (so it may be overwritten): tanh in place from
    numpy, whose vectorized tanh is ~12x faster than torch's here (torch's ~2 ns per element was most of a
    4096-state pass) and within ~1 ulp of it."""
    if type(module) is nn.Tanh and x.dtype == th.float32 and x.device.type == "cpu" and x.is_contiguous():
        array = x.numpy()
        np.tanh(array, out=array)
        return x
    return activate(module, x)


def kept_units(mask: MasksemblesMask) -> th.Tensor | None:
    """(k, w) indices of the units each mask keeps, or None if the masks are not 0/1 with equal counts.

    Made once per mask (`derived`: remade when the masks change)."""
    masks = mask._buffers["masks"]
    return derived(mask, "kept", (masks,), lambda: _kept_units(masks))


def _kept_units(masks: th.Tensor) -> th.Tensor | None:
    counts = masks.sum(1)
    if bool((masks * (1.0 - masks)).any()) or bool((counts != counts[0]).any()):
        return None
    return masks.nonzero()[:, 1].view(masks.shape[0], -1)


def _members(x: th.Tensor, k: int) -> th.Tensor:
    """A shared (N, ...) tensor as a (k, N, ...) view."""
    return x.expand(k, *x.shape)


_VIEWS: weakref.WeakKeyDictionary[nn.Module, tuple] = weakref.WeakKeyDictionary()


def _cached_views(module: nn.Module, sources: tuple[th.Tensor, ...], make):
    """`make()` (views of a layer's tensors), remade only when a source moved to other memory.

    A one-state pass costs about as much in creating views (~2 us each) as in arithmetic. A view
    shares its tensor's memory, so in-place updates (optimizer steps, load_state_dict) show
    through it; replacing the memory (`.data =`, `.to()`) changes the address, and holding the
    old view keeps the old memory from being reused at that address.
    """
    key = tuple(source.data_ptr() for source in sources)
    cached = _VIEWS.get(module)
    if cached is None or cached[0] != key:
        cached = _VIEWS[module] = (key, make())
    return cached[1]


def linear_views(layer: MemberLinear) -> tuple[th.Tensor, th.Tensor]:
    """A SHARED MemberLinear's weight (d_out, d_in) and bias (d_out,), as F.linear takes them."""
    weight, bias = layer._parameters["weight"], layer._parameters["bias"]
    return _cached_views(layer, (weight, bias), lambda: (weight.view(layer.d_out, layer.d_in), bias.view(layer.d_out)))


def mask_view(mask: MasksemblesMask) -> th.Tensor:
    """The masks as (k, 1, width), as MasksemblesMask.forward multiplies them."""
    masks = mask._buffers["masks"]
    return _cached_views(mask, (masks,), lambda: masks[:, None, :])


# --- MLP towers ----------------------------------------------------------------------------------

def dense_tower(modules: nn.Sequential, x: th.Tensor, run: Pass) -> th.Tensor:
    """An MLP tower with every member on every unit, member-major (k, N, d) from the input on.

    The reference's own tensor ops on the same shapes, without module calls: bit for bit its
    numbers (a one-state `predict` acts exactly as before; MuJoCo would amplify any rounding
    difference along an episode). The first layer runs on k copies of the input, as there:
    for a vector observation it is the cheapest layer. For every method but Masksembles on
    many states (`compact_tower`).
    """
    x, owned = _members(x, run.k), False  # owned: made by this pass, free to overwrite
    for module in modules:
        kind = type(module)
        if kind in ELEMENTWISE:
            x = activate_owned(module, x) if owned and run.fast else activate(module, x)
            continue
        if kind is MemberLinear:
            x = _dense_linear(module, x, run)
        elif kind is MasksemblesMask:
            x = x * mask_view(module)  # MasksemblesMask.forward
        elif kind is MCDropout:
            x = per_state.dropout(module, x, run.layer_seeds(module))
        else:  # exact types only: a subclass (or a patched class) may compute something else
            raise Unsupported(f"{kind.__name__} in an MLP tower")
        owned = True
    return x


def _dense_linear(layer: MemberLinear, x: th.Tensor, run: Pass) -> th.Tensor:
    """A MemberLinear on member-major (k, N, d_in) as MemberLinear.forward computes it; a SHARED layer
    also takes shared (N, d_in)."""
    if layer.mode == SHARED:
        return F.linear(x, *linear_views(layer))
    if layer.mode == ENSEMBLE:
        weight, bias = layer._parameters["weight"], layer._parameters["bias"]  # not via Module.__getattr__ (~1 us)
        if run.fast and layer.d_out <= NARROW_OUT and x.dim() == 3:
            return narrow_output(x, weight.transpose(1, 2), bias.transpose(1, 2))
        return th.baddbmm(bias, _members(x, run.k) if x.dim() == 2 else x, weight)
    return per_state.dropconnect_linear(layer, _members(x, run.k) if x.dim() == 2 else x, run.layer_seeds(layer))


def compact_tower(modules: nn.Sequential, x: th.Tensor, run: Pass, kept: dict[nn.Module, th.Tensor]
                  ) -> tuple[th.Tensor, th.Tensor | None]:
    """A Masksembles MLP tower, each member on its kept units only: (k, N, d_out) and the kept
    units of the output (None when the last layer is unmasked).

    Features-major inside: activations are (units, N), member j's block (w, N), so picking a
    member's kept units copies whole rows and every product is one (batched) matmul on
    contiguous operands. A layer followed by a mask computes only its kept outputs, from its
    input's kept units only: member j's weights are W[rows_j][:, cols_j]. The first layer
    (shared input) runs once, on all units; its mask then picks each member's rows.
    `kept` holds each mask's kept units (`kept_units`).
    """
    layers = list(modules)
    h, cols, masked_by = x.T, None, None  # cols: (k, w) the kept units of the member blocks
    for i, module in enumerate(layers):
        kind = type(module)
        if kind is MemberLinear and module.mode == SHARED:
            mask = _mask_after(layers, i) if h.dim() == 3 else None
            rows = None if mask is None else kept[mask]
            h = _features_major_linear(module, h, rows, cols, run)
            cols, masked_by = rows, mask
        elif kind is MasksemblesMask and module is not masked_by:
            if h.dim() != 2:
                raise Unsupported("a Masksembles mask after member-specific units")
            cols, masked_by = kept[module], module
            h = h.index_select(0, cols.flatten()).view(run.k, cols.shape[1], -1)
        elif kind in ELEMENTWISE:
            h = activate(module, h)
        elif kind is not MasksemblesMask:
            raise Unsupported(f"{kind.__name__} in a compact tower")
    return (_members(h.T, run.k), None) if h.dim() == 2 else (h.transpose(1, 2), cols)


def _mask_after(modules: list[nn.Module], i: int) -> MasksemblesMask | None:
    """The Masksembles mask right after layer i's activation, if there is one."""
    if i + 2 < len(modules) and type(modules[i + 1]) in ELEMENTWISE and type(modules[i + 2]) is MasksemblesMask:
        return modules[i + 2]
    return None


def _features_major_linear(layer: MemberLinear, h: th.Tensor, rows: th.Tensor | None, cols: th.Tensor | None,
                           run: Pass) -> th.Tensor:
    """W h + b on features-major activations: shared (d, N) -> (d_out, N); member blocks (k, w, N) ->
    (k, w_out, N) with member j's weights on its kept inputs (cols) and kept outputs (rows)."""
    weight, bias = layer.weight.view(layer.d_out, layer.d_in), layer.bias.view(layer.d_out, 1)
    if h.dim() == 2:
        return th.addmm(bias, weight, h)
    w, b = member_weights(layer, rows, cols, run.k, "features_major")
    return th.baddbmm(b, w, h)


#: How `member_weights` lays out member j's gathered weights (k, ., .) and bias for its batched matmul.
WEIGHT_LAYOUTS = {
    "features_major": lambda w, b: (w, b.unsqueeze(-1)),  # W_j h_j, h_j (in, N): bias (k, out, 1)
    "linear": lambda w, b: (w.transpose(1, 2), b.unsqueeze(1)),  # x_j W_j^T on a view: BLAS reads it as is
    "states_major": lambda w, b: (w.transpose(1, 2).contiguous(), b.unsqueeze(1)),  # x_j (N, in) W_j^T, stored so
}


#: Output units up to which the fast path computes a layer features-major (`narrow_output`).
NARROW_OUT = 16


def narrow_output(x: th.Tensor, weight: th.Tensor, bias: th.Tensor) -> th.Tensor:
    """(k, N, d_out) contiguous from states-major x (k, N, d_in), member weights (k, d_out, d_in), bias (k, d_out, 1).

    An action or value head (d_out 6 or 1) as W_j x_j^T, (k, d_out, N): BLAS multiplies a few rows by N columns
    ~4x faster here than N rows by a few columns (0.2 vs 0.8 ms for 4 x 1024 states, 256 -> 6)."""
    return th.baddbmm(bias, weight, x.transpose(1, 2)).transpose(1, 2).contiguous()


def member_weights(layer: MemberLinear, rows: th.Tensor | None, cols: th.Tensor | None, k: int, layout: str
                   ) -> tuple[th.Tensor, th.Tensor]:
    """A SHARED layer's weights of each member on its kept outputs (rows) and inputs (cols), in `layout`, and its
    bias: gathered once, reused while the weights and masks stay the same (`derived`)."""
    weight, bias = layer._parameters["weight"], layer._parameters["bias"]

    def make() -> tuple[th.Tensor, th.Tensor]:
        w, b = gathered_weights(weight.view(layer.d_out, layer.d_in), bias.view(layer.d_out), rows, cols, k)
        return WEIGHT_LAYOUTS[layout](w, b)

    return derived(layer, layout, (weight, bias, rows, cols), make)


def gathered_weights(weight: th.Tensor, bias: th.Tensor, rows: th.Tensor | None, cols: th.Tensor | None, k: int
                     ) -> tuple[th.Tensor, th.Tensor]:
    """Member j's (out, in) weights on its kept outputs (rows (k, w_out)) and kept inputs (cols (k, w_in)),
    stacked (k, out, in), and its bias (k, out). Picking whole rows first keeps the copy cheap."""
    if rows is not None:
        weight = weight.index_select(0, rows.flatten()).view(k, rows.shape[1], -1)
        bias = bias.index_select(0, rows.flatten()).view(k, -1)
    else:
        weight, bias = weight.expand(k, -1, -1), bias.expand(k, -1)
    if cols is not None:
        weight = weight.gather(2, cols[:, None, :].expand(-1, weight.shape[1], -1))
    return weight.contiguous(), bias.contiguous()


def states_major_tower(modules: nn.Sequential, x: th.Tensor, run: Pass, kept: dict[nn.Module, th.Tensor]
                       ) -> tuple[th.Tensor, th.Tensor | None]:
    """The fast path's Masksembles MLP tower: (k, N, d_out) contiguous, and the kept units of the output (None
    when the last layer is unmasked), each member on its kept units only, as `compact_tower`.

    States-major (k, N, units) throughout, so the outputs need no transpose and every layer is one batched
    matmul with member j's gathered weights (x_j W_j^T, cached: `member_weights`). Unlike `compact_tower`, the
    first layer (shared input) also runs per member on its kept outputs: k x kept instead of all d_out output
    units, more multiply-adds by k x kept / d_out (2 for k = 4 at scale 2) on the cheapest layer of a vector
    observation, and no copy of the kept rows out of the shared activations.
    """
    layers = list(modules)
    h, cols, masked_by, owned = x, None, None, False  # cols: (k, w) the kept units of the member blocks
    for i, module in enumerate(layers):
        kind = type(module)
        if kind is MemberLinear and module.mode == SHARED:
            mask = _mask_after(layers, i)
            rows = None if mask is None else kept[mask]
            if h.dim() == 2 and rows is None:
                h = F.linear(h, *linear_views(module))
            elif h.dim() == 3 and rows is None and module.d_out <= NARROW_OUT:
                h = narrow_output(h, *member_weights(module, None, cols, run.k, "features_major"))
            else:
                w, b = member_weights(module, rows, cols, run.k, "states_major")
                h = th.baddbmm(b, _members(h, run.k) if h.dim() == 2 else h, w)
            cols, masked_by, owned = rows, mask, True
        elif kind in ELEMENTWISE:
            h = activate_owned(module, h) if owned else activate(module, h)  # fast path only
        elif kind is not MasksemblesMask or module is not masked_by:  # a mask only right after linear + activation
            raise Unsupported(f"{kind.__name__} where a states-major tower does not take it")
    return (_members(h, run.k), None) if h.dim() == 2 else (h, cols)


def mlp_tower(modules: nn.Sequential, x: th.Tensor, run: Pass) -> tuple[th.Tensor, th.Tensor | None]:
    """(k, N, d_out) of a tower, and the kept units of its output when it holds only those."""
    if run.compact and any(type(m) is MasksemblesMask for m in modules):
        kept = {m: kept_units(m) for m in modules if type(m) is MasksemblesMask}
        if all(units is not None for units in kept.values()):
            return (states_major_tower if run.fast else compact_tower)(modules, x, run, kept)
    return dense_tower(modules, x, run), None


# --- the Nature CNN -------------------------------------------------------------------------------

@dataclass(slots=True)
class Acts:
    """Activations of all members between two layers of the CNN.

    layout "shared":  (N, ...), the same for every member (no member-specific layer yet);
           "members": (k, N, ...), member-major;
           "grouped": (N, k*C, H, W), member j's channels in group j (grouped convolutions).
    kept: (k, w) channel or unit indices when member j holds only what its Masksembles mask
    keeps (`kept_by` is that mask); None when dense.
    """

    x: th.Tensor
    layout: str
    kept: th.Tensor | None = None
    kept_by: nn.Module | None = None


def as_members(a: Acts, k: int) -> th.Tensor:
    """(k, N, ...) view of dense activations in any layout."""
    if a.kept is not None:
        raise Unsupported("kept units where dense activations are needed")
    if a.layout == "shared":
        return _members(a.x, k)
    if a.layout == "grouped":
        n = a.x.shape[0]
        return a.x.view(n, k, a.x.shape[1] // k, *a.x.shape[2:]).transpose(0, 1)
    return a.x


def conv(layer: MemberConv2d, a: Acts, run: Pass) -> Acts:
    """A MemberConv2d on shared, grouped or member-major images."""
    k = run.k
    if layer.mode == DROPCONNECT:
        if a.kept is not None:
            raise Unsupported("DropConnect after Masksembles")
        shared = a.layout == "shared"
        x = a.x if shared else as_members(a, k)
        return Acts(per_state.dropconnect_conv(layer, x, shared, k, run.layer_seeds(layer)), "members")
    if layer.mode == ENSEMBLE:
        weight, bias = layer.weight.view(-1, *layer.weight.shape[2:]), layer.bias.view(-1)
        if a.layout == "shared":  # all k members' kernels as one wider convolution of the one input
            return Acts(F.conv2d(a.x, weight, bias, stride=layer.stride), "grouped")
        x = a.x if a.layout == "grouped" else _grouped(as_members(a, k))
        return Acts(F.conv2d(x, weight, bias, stride=layer.stride, groups=k), "grouped")
    weight, bias = layer.weight.squeeze(0), layer.bias.squeeze(0)
    if a.kept is not None:  # member j's kernels on its kept input channels only: one grouped convolution
        w, b = _gathered_conv(layer, a.kept, run)
        return Acts(F.conv2d(a.x, w, b, stride=layer.stride, groups=k), "grouped")
    if a.layout == "shared":
        return Acts(F.conv2d(a.x, weight, bias, stride=layer.stride), "shared")
    if a.layout == "grouped":  # (N, k*C, H, W) is N*k images of C channels, and back
        n = a.x.shape[0]
        y = F.conv2d(a.x.reshape(n * k, -1, *a.x.shape[2:]), weight, bias, stride=layer.stride)
        return Acts(y.view(n, -1, *y.shape[2:]), "grouped")
    y = F.conv2d(a.x.reshape(-1, *a.x.shape[2:]), weight, bias, stride=layer.stride)  # k*N images
    return Acts(y.view(k, -1, *y.shape[1:]), "members")


def _grouped(x: th.Tensor) -> th.Tensor:
    """(k, N, C, H, W) -> (N, k*C, H, W)."""
    return x.transpose(0, 1).reshape(x.shape[1], -1, *x.shape[3:])


def _gathered_conv(layer: MemberConv2d, kept: th.Tensor, run: Pass) -> tuple[th.Tensor, th.Tensor]:
    """Member j's kernels on its kept input channels, stacked for a grouped convolution."""
    weight, bias = layer._parameters["weight"], layer._parameters["bias"]

    def make() -> tuple[th.Tensor, th.Tensor]:
        kernels = weight.squeeze(0)  # (C', C, kh, kw)
        gathered = kernels[:, kept].transpose(0, 1).reshape(-1, kept.shape[1], *kernels.shape[2:])
        return gathered.contiguous(), bias.squeeze(0).repeat(run.k)

    return derived(layer, "conv", (weight, bias, kept), make)


def masksembles(mask: MasksemblesMask, a: Acts, run: Pass) -> Acts:
    """The fixed masks: already applied if the layer before computed only the kept units; images
    shared by the members become each member's kept channels; else the reference's multiplication."""
    if a.kept is not None and a.kept_by is mask:
        return a  # the mask is 1 on the kept units
    kept = kept_units(mask) if run.compact and a.layout == "shared" and a.x.dim() == 4 else None
    if kept is not None:  # (N, k*w, H, W), group j = member j's kept channels
        return Acts(a.x.index_select(1, kept.flatten()), "grouped", kept, mask)
    x = as_members(a, run.k)
    return Acts(x * mask.masks.view(run.k, 1, -1, *(1,) * (x.dim() - 3)), "members")


def linear(layer: MemberLinear, a: Acts, run: Pass) -> Acts:
    """A MemberLinear (fc or a head) on features; a Masksembles member on its kept inputs only."""
    if a.kept is None:
        return Acts(_dense_linear(layer, a.x if a.layout == "shared" else as_members(a, run.k), run),
                    "shared" if a.layout == "shared" and layer.mode == SHARED else "members")
    if layer.mode != SHARED or a.layout != "members":
        raise Unsupported("kept units into a layer with member weights")
    return Acts(_kept_linear(layer, a.x, None, a.kept, run), "members")


def _kept_linear(layer: MemberLinear, x: th.Tensor, rows: th.Tensor | None, cols: th.Tensor | None, run: Pass
                 ) -> th.Tensor:
    """(k, N, out') from member-major x (k, N, in'): member j's weights on its kept rows and cols."""
    w, b = member_weights(layer, rows, cols, run.k, "linear")
    return th.baddbmm(b, x, w)


def _fc_with_mask(net: MemberNatureCNN, a: Acts, run: Pass) -> Acts:
    """fc on member-major features; with Masksembles after it on many states, each member's kept units only."""
    x = Acts(as_members(a, run.k).flatten(2), "members")
    mask = net.after_fc if type(net.after_fc) is MasksemblesMask else None
    if mask is not None and run.compact and (rows := kept_units(mask)) is not None:
        return Acts(_kept_linear(net.fc, x.x, rows, None, run), "members", rows, mask)
    return linear(net.fc, x, run)


def stochastic(module: nn.Module, a: Acts, run: Pass) -> Acts:
    """The layer after conv1 or fc: a Masksembles mask, MC Dropout, or nothing."""
    kind = type(module)
    if kind is MasksemblesMask:
        return masksembles(module, a, run)
    if kind is MCDropout:
        return Acts(per_state.dropout(module, as_members(a, run.k), run.layer_seeds(module)), "members")
    if kind is nn.Identity:
        return a
    raise Unsupported(f"{kind.__name__} as a stochastic layer")


def _relu(a: Acts) -> Acts:
    return Acts(th.relu(a.x), a.layout, a.kept, a.kept_by)


def cnn_trunk(net: MemberNatureCNN, x: th.Tensor, run: Pass) -> Acts:
    """`MemberNatureCNN.trunk`, layer by layer, from images shared by the members."""
    convs, linears = (net.conv1, net.conv2, net.conv3), (net.fc, net.policy_head, net.value_head)
    if any(type(m) is not MemberConv2d for m in convs) or any(type(m) is not MemberLinear for m in linears):
        raise Unsupported("a Nature CNN with other layer types")
    a = stochastic(net.after_conv1, _relu(conv(net.conv1, Acts(x, "shared"), run)), run)
    a = _relu(conv(net.conv3, _relu(conv(net.conv2, a, run)), run))
    return stochastic(net.after_fc, _relu(_fc_with_mask(net, a, run)), run)


def dense_members(a: Acts, k: int, width: int) -> th.Tensor:
    """(k, N, width) with zeros at the units a Masksembles mask drops: the reference's masked activations."""
    if a.kept is None:
        return as_members(a, k)
    return _scatter_kept(a.x, a.kept, width)


def _scatter_kept(x: th.Tensor, kept: th.Tensor, width: int) -> th.Tensor:
    return x.new_zeros(*x.shape[:-1], width).scatter_(-1, kept[:, None, :].expand(x.shape), x)


# --- networks and entry points ----------------------------------------------------------------------

def network_members(net: MemberActorCritic, features: th.Tensor, run: Pass, actor: bool, critic: bool
                    ) -> tuple[th.Tensor | None, th.Tensor | None]:
    """(k, N, A) action parameters and (k, N, 1) values of all members on `features` (one chunk)."""
    if type(net) is MemberMLP:  # exact types: a subclass may compute something else
        pi = mlp_tower(net.policy_tower, features, run)[0] if actor else None
        vf = mlp_tower(net.value_tower, features, run)[0] if critic else None
        return pi, vf
    if type(net) is MemberNatureCNN:
        z = cnn_trunk(net, features, run)
        pi = as_members(linear(net.policy_head, z, run), run.k) if actor else None
        vf = as_members(linear(net.value_head, z, run), run.k) if critic else None
        return pi, vf
    raise Unsupported(type(net).__name__)


def last_hidden(net: MemberActorCritic, features: th.Tensor, run: Pass) -> th.Tensor:
    """(k, N, H): the input of the action head, dense (masked units are zeros), as the reference's."""
    if type(net) is MemberMLP:
        x, kept = mlp_tower(net.policy_tower[:-1], features, run)
        return x if kept is None else _scatter_kept(x, kept, net.policy_tower[-1].d_in)
    if type(net) is MemberNatureCNN:
        return dense_members(cnn_trunk(net, features, run), run.k, net.fc.d_out)
    raise Unsupported(type(net).__name__)


def _features(policy, obs: th.Tensor) -> th.Tensor:
    """SB3's `extract_features`, without a module call for flat observations."""
    if type(policy.features_extractor) is FlattenExtractor:
        return preprocess_obs(obs, policy.observation_space, policy.normalize_images).flatten(1)
    return policy.extract_features(obs)


def _by_chunks(policy, obs: th.Tensor, state_seeds: np.ndarray | None, fn, path: str = "exact") -> list:
    """`fn(net, features, run)` on chunks of states (images) or all at once (vectors), on `path` (`PATHS`)."""
    net = policy.mlp_extractor
    n_states = obs.shape[0]
    seeds = None
    if state_seeds is not None:
        seeds = per_state.StateSeeds.of(net, state_seeds)
        if len(seeds.seeds) != n_states:
            raise ValueError(f"got {len(seeds.seeds)} state seeds for {n_states} states; pass one seed per state")
    compact = n_states >= COMPACT_MIN_STATES
    run = Pass(net.k, seeds, compact, fast=fast_arithmetic(path, n_states))
    step = IMAGE_CHUNK_STATES if isinstance(net, MemberNatureCNN) else max(1, n_states)
    return [fn(net, _features(policy, obs[start:start + step]), run.chunk(start, min(n_states, start + step), n_states))
            for start in range(0, n_states, step)]


def _join(parts: list[th.Tensor]) -> th.Tensor:
    return parts[0] if len(parts) == 1 else th.cat(parts, dim=1)


def fast_members(policy, obs: th.Tensor, state_seeds: np.ndarray | None, actor: bool = True, critic: bool = True,
                 path: str = "exact") -> tuple[th.Tensor | None, th.Tensor | None]:
    """All members on `obs` through the lean path; MC layers use `state_seeds`. Raises Unsupported."""
    parts = _by_chunks(policy, obs, state_seeds, lambda net, x, run: network_members(net, x, run, actor, critic),
                       path)
    return (_join([p for p, _ in parts]) if actor else None), (_join([v for _, v in parts]) if critic else None)


def fast_last_hidden(policy, obs: th.Tensor, state_seeds: np.ndarray | None, path: str = "exact") -> th.Tensor:
    """(k, N, H) last hidden layer of all members through the lean path. Raises Unsupported."""
    return _join(_by_chunks(policy, obs, state_seeds, last_hidden, path))


def _reference_context(net: nn.Module, state_seeds: np.ndarray | None):
    stochastic_net = state_seeds is not None and any(is_stochastic(m) for m in net.modules())
    return per_state_masks(net, state_seeds) if stochastic_net else nullcontext()


def reference_members(policy, obs: th.Tensor, state_seeds: np.ndarray | None, actor: bool = True,
                      critic: bool = True) -> tuple[th.Tensor | None, th.Tensor | None]:
    """The member network's own modules in the "all" layout, inside `per_state_masks`: the definition."""
    net = policy.mlp_extractor
    features = policy.extract_features(obs)
    with _reference_context(net, state_seeds):
        return net.members(features, "all", actor=actor, critic=critic)


def reference_last_hidden(policy, obs: th.Tensor, state_seeds: np.ndarray | None) -> th.Tensor:
    """The reference modules' last hidden layer: the policy tower without its head, or the CNN trunk."""
    net = policy.mlp_extractor
    features = policy.extract_features(obs)
    x = _members(features, net.k)
    with _reference_context(net, state_seeds):
        return net.policy_tower[:-1](x) if hasattr(net, "policy_tower") else net.trunk(x)


def members(policy, obs: th.Tensor, state_seeds: np.ndarray | None, actor: bool = True, critic: bool = True,
            path: str = "exact") -> tuple[th.Tensor | None, th.Tensor | None]:
    """(k, N, A) and (k, N, 1): the lean path (`path`, one of PATHS) without autograd on a known network, else the
    reference."""
    check_path(path)
    if not th.is_grad_enabled():
        try:
            return fast_members(policy, obs, state_seeds, actor, critic, path)
        except Unsupported:
            pass
    return reference_members(policy, obs, state_seeds, actor, critic)


def last_hidden_members(policy, obs: th.Tensor, state_seeds: np.ndarray | None, path: str = "exact") -> th.Tensor:
    """(k, N, H) last hidden layer: the lean path (`path`) without autograd on a known network, else the reference."""
    check_path(path)
    if not th.is_grad_enabled():
        try:
            return fast_last_hidden(policy, obs, state_seeds, path)
        except Unsupported:
            pass
    return reference_last_hidden(policy, obs, state_seeds)
