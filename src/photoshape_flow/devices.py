"""The torch device and thread count the networks and the descriptor search run with.

One resolution rule for every stage, from ``settings.device`` (``PHOTOSHAPE_DEVICE``):
``"auto"`` is cuda when torch sees a CUDA device, else cpu; ``"cpu"`` is cpu; ``"cuda"`` (or
``"cuda:N"``) without a CUDA device is an error rather than a silent fall back to cpu, so a run
asked to use the GPU never quietly takes hours on the CPU. torch is imported lazily: importing this
module costs nothing.
"""

from __future__ import annotations


def resolve_device(setting: str = "auto") -> str:
    """The torch device string for a ``settings.device`` value ("auto", "cpu", "cuda", "cuda:N")."""
    import torch

    if setting == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if setting.startswith("cuda") and not torch.cuda.is_available():
        raise RuntimeError(
            f"settings.device (PHOTOSHAPE_DEVICE) is {setting!r} but torch sees no CUDA device; "
            "use 'auto' or 'cpu'"
        )
    return setting


def set_torch_threads(threads: int) -> None:
    """Limit torch's intra-op threads to ``settings.torch_threads``; 0 leaves torch's default (all cores)."""
    if threads > 0:
        import torch

        torch.set_num_threads(threads)
