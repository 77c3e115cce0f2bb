"""The network's inference step: ``model.prepare_for_inference()`` (the one place that documents it).

The modules of the network are its definition: training, and any forward that records gradients, runs
them as written. For inference without autograd, a *prepared* model runs the same function (up to float
rounding) in forms that are faster on the CPU and lighter on memory:

* every eval BatchNorm folded into the convolution before it (``fuse_conv_bn_weights``), weights in
  channels-last memory, where oneDNN runs the thin full-resolution convolutions about twice as fast
  (FPN encoder and decoder, SVA upsampler, visibility networks);
* the 3-D U-Nets of stages 2-4 as 2-D convolutions: over the depths as a batch, one per depth tap,
  or depth-banded (:mod:`.regularization`); the last FPN level in row bands (:mod:`.fpn`);
* activations, residual sums and cost-volume buffers in place, images one at a time through the FPN
  and the FMT pathway, features freed as soon as they are used. This part needs no derived weights,
  so a plain ``model.eval()`` forward under ``torch.no_grad()`` runs it too (:func:`lean`): the
  path a PyTorch user calls first gets the same memory savings (the derived weights bring the speed).

Rules:

* :func:`prepare` (``model.prepare_for_inference()``, which also switches to eval mode) derives these
  weights once from the current parameters and buffers, and keeps a copy of the tensors they come from.
* A forward uses them only inside :func:`session` of the prepared model (``MVSFormerPP.forward`` and
  ``encode_images`` open one), without autograd, and only while those tensors are unchanged:
  ``train()`` and ``load_state_dict`` drop them, and any other change (an optimiser step, an EMA update
  through ``.data``, ``.to()``, replacing a parameter, a sub-module put in training mode) is found by
  comparing with the copy when the next session opens, which drops them too. A model whose forms were
  dropped runs the plain modules until ``prepare_for_inference()`` is called again: derived weights
  can never be stale.
* A module takes part by defining ``build_inference_forms()`` (derived tensors from its own parameters
  and buffers; ``inference_sources``, a tuple of child names, narrows which ones when the forms use
  only a few) and reading them back with :func:`forms` in its forward; code that only needs to know
  whether it may work in place and image by image asks :func:`lean` (true in any session without
  autograd whose model is all in eval mode, prepared or not).
"""

from __future__ import annotations

import contextlib
import contextvars

import torch
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_weights

_ACTIVE: contextvars.ContextVar[bool] = contextvars.ContextVar("mvsformerpp_inference", default=False)
_LEAN: contextvars.ContextVar[bool] = contextvars.ContextVar("mvsformerpp_lean", default=False)
_FORMS = "_inference_forms"
_SOURCES = "_inference_sources"


def active() -> bool:
    """Whether the current forward runs a prepared model without autograd (its forms may be used)."""
    return _ACTIVE.get()


def lean() -> bool:
    """Whether the current forward runs without autograd with every module in eval mode, prepared or
    not: activations may be overwritten in place and images run one at a time (eval BatchNorm makes
    that the batch's result), as nothing keeps the intermediate tensors for a backward pass."""
    return _LEAN.get()


def forms(module: nn.Module):
    """The derived tensors of ``module`` when the current forward may use them, else None."""
    return module.__dict__.get(_FORMS) if _ACTIVE.get() else None


def prepare(model: nn.Module) -> nn.Module:
    """Switch ``model`` to eval mode and build the inference forms of every module that has them."""
    release(model)
    model.eval()
    sources = []
    for module in model.modules():
        build = getattr(type(module), "build_inference_forms", None)
        if build is None:
            continue
        with torch.no_grad():
            module.__dict__[_FORMS] = build(module)
        parts = getattr(module, "inference_sources", None)
        owners = [o for part in parts for o in module.get_submodule(part).modules()] if parts else module.modules()
        for owner in owners:
            for table in (owner._parameters, owner._buffers):
                for name, t in table.items():
                    if t is not None and t.is_floating_point():
                        sources.append((owner, table is owner._parameters, name, t.detach().clone()))
    model.__dict__[_SOURCES] = sources
    return model


def release(model: nn.Module) -> None:
    """Drop the inference forms of ``model`` (it runs the plain modules until prepared again)."""
    model.__dict__.pop(_SOURCES, None)
    for module in model.modules():
        module.__dict__.pop(_FORMS, None)


def is_prepared(model: nn.Module) -> bool:
    """Whether ``model`` holds inference forms that match its current parameters, buffers and mode;
    forms that no longer match are dropped here."""
    sources = model.__dict__.get(_SOURCES)
    if sources is None:
        return False
    for owner, is_param, name, copy in sources:
        t = (owner._parameters if is_param else owner._buffers).get(name)
        if (owner.training or t is None or t.device != copy.device or t.dtype != copy.dtype
                or t.shape != copy.shape or not torch.equal(t.detach(), copy)):
            release(model)
            return False
    return True


@contextlib.contextmanager
def session(model: nn.Module):
    """Run the body with ``model``'s inference forms if it is prepared and autograd is off, and lean
    (:func:`lean`) whenever autograd is off and the model is all in eval mode."""
    no_grad = not torch.is_grad_enabled()
    token = _ACTIVE.set(no_grad and is_prepared(model))
    lean_token = _LEAN.set(no_grad and not any(m.training for m in model.modules()))
    try:
        yield
    finally:
        _LEAN.reset(lean_token)
        _ACTIVE.reset(token)


def fused_conv_bn(conv: nn.Module, bn: nn.Module | None = None, weight: torch.Tensor | None = None,
                  memory_format: torch.memory_format = torch.channels_last):
    """(weight, bias) of ``conv`` followed by eval-mode ``bn`` (if given) as one convolution, detached.

    ``weight`` replaces ``conv.weight`` (for convolutions composed beforehand); transposed
    convolutions are recognised by their type.
    """
    w = conv.weight if weight is None else weight
    b = conv.bias
    if bn is not None:
        transposed = isinstance(conv, nn.modules.conv._ConvTransposeNd)
        w, b = fuse_conv_bn_weights(w, b, bn.running_mean, bn.running_var, bn.eps, bn.weight, bn.bias,
                                    transpose=transposed)
    w = w.detach()
    if w.dim() == 4:
        w = w.contiguous(memory_format=memory_format)
    return w, None if b is None else b.detach()
