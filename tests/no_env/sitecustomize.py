"""Makes building an environment impossible in every Python process that has this folder on PYTHONPATH.

tests/pipeline/test_pipeline.py rebuilds the `tiny` profile's tables and figures with it: DVC, the stage commands
and the notebooks' kernels all start Python, and each loads this file. Rebuilding must only read committed files
(MuJoCo's last float bits differ across CPUs; a simulated number would move), so gymnasium's `make`, MuJoCo's model
loading and compiling, and the ALE's Atari env raise here. The patches apply when their package is first imported,
so a process that never imports them pays nothing.
"""

from __future__ import annotations

import importlib.abc
import sys
from collections.abc import Callable
from types import ModuleType

MESSAGE = "the rebuild tried to build an environment ({}): rebuilding must only read committed files"


def _forbidden(what: str) -> Callable:
    def refuse(*args, **kwargs):
        raise RuntimeError(MESSAGE.format(what))

    return refuse


def _patch_gymnasium(module: ModuleType) -> None:
    module.make = _forbidden("gymnasium.make")
    module.make_vec = _forbidden("gymnasium.make_vec")


def _patch_registration(module: ModuleType) -> None:
    module.make = _forbidden("gymnasium.envs.registration.make")
    module.make_vec = _forbidden("gymnasium.envs.registration.make_vec")


def _patch_mujoco(module: ModuleType) -> None:
    for name in ("from_xml_string", "from_xml_path", "from_binary_path"):
        setattr(module.MjModel, name, staticmethod(_forbidden(f"mujoco.MjModel.{name}")))
    module.MjSpec.compile = _forbidden("mujoco.MjSpec.compile")


def _patch_ale_env(module: ModuleType) -> None:
    module.AtariEnv.__init__ = _forbidden("ale_py.env.AtariEnv")


PATCHES: dict[str, Callable[[ModuleType], None]] = {
    "gymnasium": _patch_gymnasium, "gymnasium.envs.registration": _patch_registration, "mujoco": _patch_mujoco,
    "ale_py.env": _patch_ale_env}


class _PatchAfterImport(importlib.abc.MetaPathFinder):
    """Finds the patched modules as the other finders would, and patches each right after it executes."""

    def find_spec(self, name, path, target=None):
        if name not in PATCHES:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None and spec.loader is not None:
                execute = spec.loader.exec_module

                def execute_and_patch(module: ModuleType, execute=execute) -> None:
                    execute(module)
                    PATCHES[module.__name__](module)

                spec.loader.exec_module = execute_and_patch
                return spec
        return None


sys.meta_path.insert(0, _PatchAfterImport())
