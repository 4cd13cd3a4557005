"""What the fused step's implementations share: the feature-source codes they dispatch on, and the
cache folder their compiled code lives in (neither needs numba or a compiler to import)."""
from __future__ import annotations

import contextlib
import os
import sys
import uuid
from pathlib import Path

from bcfpipe.formats.addressing import wrap_codes
from bcfpipe.process_env import KERNELS_ENV, environment, kernels_dir

FREE_BC6H, FREE_BC7, BLOCK_BC6H, BLOCK_BC7 = 0, 1, 2, 3  # free texels (warm-up) or blocks, per format
# A slot's first field: not sampled, a trained level, or a fixed one: a level written as it was
# encoded (a T_0 of principal components, BC7 in any mode), its UNORM8 values stored like free
# texels, sampled with no gradient.
INACTIVE, TRAINED, FIXED = 0, 1, 2
# A model's addressing as the kernels take it: S's mode in bits 0-1, T's in bits 2-3.
WRAP_REPEAT, WRAP_CLAMP, WRAP_MIRROR = 0, 1, 2


def wrap_code(wrap) -> int:
    """The kernels' int for an addressing (one mode or an (S, T) pair): bcfpipe.formats.addressing's codes,
    which these constants name."""
    s, t = wrap_codes(wrap)
    return s | t << 2


SAID_ENV = "BCFPIPE_KERNEL_SAID"  # set by a build for its workers: the file whose creator says a fallback


@contextlib.contextmanager
def kernels_in(cache_root: str | os.PathLike | None):
    """Within the block, this process and the workers it starts keep compiled kernels under
    ``cache_root/kernels`` (a build's --cache; None keeps the default), and a fallback from the
    compiled kernel is said once for them all (`say_once`), not once per worker."""
    with environment(KERNELS_ENV, None if cache_root is None else str(Path(cache_root) / "kernels")):
        said = Path(kernels_dir()) / f".said-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        try:
            with environment(SAID_ENV, str(said)):
                yield
        finally:
            with contextlib.suppress(OSError):
                said.unlink()


def say_once(line: str) -> None:
    """Print ``line`` on stderr: once per build, where `kernels_in` set one up (the worker that
    creates its file first says it), else once per call."""
    said = os.environ.get(SAID_ENV)
    if said:
        try:
            Path(said).parent.mkdir(parents=True, exist_ok=True)
            os.close(os.open(said, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return
        except OSError:
            pass  # no folder to agree in: every worker says it
    print(line, file=sys.stderr, flush=True)
