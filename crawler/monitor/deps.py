"""The laptop's optional libraries (the `[monitor]` extra), imported when a command first needs them."""

from __future__ import annotations

import importlib

from ..errors import CrawlerError

INSTALL = "pip install 'crawlerd[monitor]'"
_PYPI = {"rich": "rich", "matplotlib": "matplotlib", "mcap": "mcap", "foxglove": "foxglove-sdk"}


class MissingExtra(CrawlerError, ImportError):
    """An optional package a command needs is not installed; the message has the install line."""


def require(module: str, purpose: str, instead: str = ""):
    """import `module` or say in one line what to install (and what works without it)."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        top = module.split(".")[0]
        hint = f"; {instead}" if instead else ""
        raise MissingExtra(f"{purpose} needs {_PYPI.get(top, top)} ({exc}): {INSTALL} "
                           f"or pip install {_PYPI.get(top, top)}{hint}") from None
