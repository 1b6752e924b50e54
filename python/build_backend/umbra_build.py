"""umbra's PEP 517 build backend: maturin's, with cargo's ``--ignore-rust-version``.

umbra's USD reader, the ``openusd`` crate 0.8, declares Rust 1.96 in its manifest and builds
and passes umbra's tests on Rust 1.95 (docs/usd.md#toolchain). Cargo refuses such a crate
unless it is given ``--ignore-rust-version``; this backend adds the flag to maturin's build
arguments (``--config-settings build-args=...`` or ``MATURIN_PEP517_ARGS``, whichever the user
gave) so that ``pip install ./python`` needs nothing typed. Every other hook is maturin's.
"""

from __future__ import annotations

import os
import shlex
from typing import Any, Mapping

import maturin
from maturin import (  # noqa: F401  (re-exported PEP 517 hooks)
    build_sdist,
    get_requires_for_build_editable,
    get_requires_for_build_sdist,
    get_requires_for_build_wheel,
)

FLAG = "--ignore-rust-version"


def _with_flag(config_settings: Mapping[str, Any] | None) -> dict[str, Any]:
    """The settings with FLAG appended to the build arguments maturin would read."""
    settings = dict(config_settings or {})
    key = "maturin.build-args" if "maturin.build-args" in settings else "build-args"
    given = settings.get(key)
    if given is None:
        args = shlex.split(os.getenv("MATURIN_PEP517_ARGS", ""))
    elif isinstance(given, str):
        args = shlex.split(given)
    else:
        args = list(given)
    if FLAG not in args:
        args.append(FLAG)
    settings[key] = args
    return settings


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    return maturin.build_wheel(wheel_directory, _with_flag(config_settings), metadata_directory)


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    return maturin.build_editable(wheel_directory, _with_flag(config_settings), metadata_directory)


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    return maturin.prepare_metadata_for_build_wheel(metadata_directory, _with_flag(config_settings))


prepare_metadata_for_build_editable = prepare_metadata_for_build_wheel
