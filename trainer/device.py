"""Where training runs and in which precision: chosen once per run, per machine.

Neither changes what a model means: noise is drawn on the CPU from the run's
seeded generator whatever the device, checkpoints load on any device, and the
exported model is float32 either way. The precision is a speed choice whose
effect on quality is measured (README, docs/EVALUATION.md):

- CPU with native bf16 (AVX512-BF16 or AMX): the convolutions run under bf16
  autocast, measured 1.2-1.5x faster per iteration here at the same quality.
  Without native bf16, oneDNN emulates it and it is many times slower, so
  such CPUs stay in float32.
- CUDA: TF32 for convolutions and matrix products (float32 range and storage,
  a 10-bit mantissa in the products), the usual setting for GAN training on
  Ampere and later; the decoder's occupancy is float32 everywhere.
"""

import ctypes
import ctypes.util
from contextlib import nullcontext
from dataclasses import dataclass

import torch

from sinshape.core.errors import InputError

DEVICES = ("auto", "cpu", "cuda", "cuda:N")
PRECISIONS = ("auto", "fp32", "bf16")


@dataclass(frozen=True)
class Placement:
    """A device, the precision used on it, and why they were picked."""

    device: torch.device
    precision: str  # "fp32", "tf32" (CUDA) or "bf16"
    reason: str

    def activate(self, shapes_vary: bool = False) -> None:
        """Set the process-wide switches this placement needs.

        cuDNN's autotuner times every kernel for each new input shape: worth
        it where a level keeps one grid size, ruinous where shapes vary
        (boxes clipped at the grid's edge: measured 5.5 s an iteration at
        54^3 on an H100 with it, 0.2 s without).
        """
        if self.device.type == "cpu":
            keep_freed_memory()
        if self.device.type == "cuda":
            torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = self.precision == "tf32"
            torch.backends.cudnn.benchmark = not shapes_vary

    def autocast(self):
        """The context training steps run in.

        Its weight cache is off: autocast would otherwise keep the first bf16
        copy of every weight for the whole context, and the optimiser steps
        inside it would be invisible to later forward passes.
        """
        if self.precision != "bf16":
            return nullcontext()
        return torch.autocast(self.device.type, dtype=torch.bfloat16, cache_enabled=False)

    def describe(self) -> str:
        return f"{self.device} ({self.precision}): {self.reason}"


# glibc's mallopt parameters, and the largest mmap threshold it accepts.
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_MAX = 32 << 20


def keep_freed_memory() -> bool:
    """Have glibc's malloc keep freed memory for reuse; False where it is not glibc.

    A training step frees and allocates again the same large tensors (4-140 MB
    per iteration at the paper's level sizes). By default glibc serves many of
    them with fresh pages from the OS and hands freed ones back, so every step
    page-faults and zeroes them again: measured 5-20% of an iteration on a
    2-core CPU (minor faults per iteration: 33,000 at 128x36x60; with this, a
    few hundred). Blocks up to 32 MB now come from the heap, and the heap is
    not trimmed: the process keeps its peak memory until it exits, which a
    training run reaches anyway.
    """
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c")).mallopt
    except (OSError, AttributeError, TypeError):  # no C library found, or not glibc (macOS)
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_MAX)) and bool(mallopt(M_TRIM_THRESHOLD, 2**31 - 1))


def native_bf16() -> bool:
    """Whether this CPU computes bf16 in hardware (AVX512-BF16 or AMX tiles)."""
    checks = [getattr(torch.cpu, name, None) for name in ("_is_avx512_bf16_supported", "_is_amx_tile_supported")]
    return any(check is not None and check() for check in checks)


def parse_device(name: str) -> torch.device:
    """'cpu', 'cuda' or 'cuda:N' -> a torch.device that exists here."""
    try:
        device = torch.device(name)
    except RuntimeError:
        device = None
    if device is None or device.type not in ("cpu", "cuda"):
        raise InputError(f"device must be one of {', '.join(DEVICES)}, got {name!r}")
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise InputError(f"device {name!r}: torch {torch.__version__} sees no CUDA GPU "
                             f"({'a CPU-only build' if torch.version.cuda is None else 'no usable GPU or driver'})")
        if (device.index or 0) >= torch.cuda.device_count():
            raise InputError(f"device {name!r}: torch sees {torch.cuda.device_count()} CUDA GPU(s)")
    return device


def choose(device: str = "auto", precision: str = "auto") -> Placement:
    """Resolve 'auto' for the device and the precision on this machine."""
    if precision not in PRECISIONS:
        raise InputError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if device == "auto":
        if torch.cuda.is_available():
            picked, reason = torch.device("cuda"), f"auto: torch sees {torch.cuda.get_device_name(0)}"
        else:
            why = "a CPU-only build" if torch.version.cuda is None else "no CUDA GPU found"
            picked, reason = torch.device("cpu"), f"auto: torch {torch.__version__} is {why}"
    else:
        picked, reason = parse_device(device), "asked for"

    if precision == "fp32":
        return Placement(picked, "fp32", reason + "; float32 asked for")
    if picked.type == "cuda":
        if precision == "bf16":
            return Placement(picked, "bf16", reason + "; bf16 autocast asked for")
        return Placement(picked, "tf32", reason + "; TF32 products on CUDA")
    if native_bf16():
        return Placement(picked, "bf16", reason + "; bf16 autocast: this CPU has native bf16")
    if precision == "bf16":
        raise InputError("`precision` bf16: this CPU has no native bf16 (AVX512-BF16 or AMX), where it is "
                         "many times slower than float32; use `precision` fp32 or auto", "precision")
    return Placement(picked, "fp32", reason + "; float32: this CPU has no native bf16")
