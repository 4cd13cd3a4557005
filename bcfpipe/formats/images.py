"""Reading a source image with the decoder's error state checked (every reader of texels uses this).

OpenImageIO reports a damaged file in two ways: ``read_image`` returns None, or it returns pixels
and leaves the error on the ImageInput (a JPEG cut short decodes to grey rows with "Premature end
of JPEG file"). An ImageBuf read drops the second kind, so a truncated JPEG would train, scan and
render as if it were whole. `read` checks both, and names the user's file, not a copy of it.
"""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from dataclasses import dataclass

import numpy as np

from bcfpipe.errors import InputError

__all__ = ["ImageReadError", "MissingChannel", "Image", "read", "probe", "channel_index", "FLOAT_TYPES"]

FLOAT_TYPES = ("half", "float", "double")
MAX_TEXELS = 16384 * 16384
MAX_CHANNELS = 64


class ImageReadError(InputError):
    """An image is missing, empty, or damaged (OpenImageIO reported an error): exit code 2."""


class MissingChannel(InputError):
    """A file lacks the channel a texture reads (e.g. ``a`` of an RGB file)."""


@dataclass(frozen=True)
class Image:
    """The first subimage's level 0: ``pixels`` (H, W, C) at the stored type or float32."""

    pixels: np.ndarray
    names: tuple[str, ...]  # channel names, upper case
    format: str  # OpenImageIO's stored base type, e.g. uint8, half

    @property
    def is_float(self) -> bool:
        return self.format in FLOAT_TYPES


def _first_line(text: str) -> str:
    return next((ln.strip() for ln in text.splitlines() if ln.strip()), "")


def _why(text: str, name: str, local: str) -> str:
    """OpenImageIO's message on one line, without the (temporary) path it was given."""
    why = _first_line(text) or "unknown error"
    for p in {local, os.path.basename(local)}:
        why = why.replace(f'("{p}")', "").replace(p, os.path.basename(name))
    return " ".join(why.split())


@contextlib.contextmanager
def _native_stderr(keep: list[bool]):
    """Hold what native decoders print on file descriptor 2 (libpng writes "libpng error: ..."
    itself) and pass it on only if ``keep[0]`` is still true afterwards: a failed read is reported
    once, in our own line."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):
        yield
        return
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            if keep[0]:
                held.seek(0)
                data = held.read()
                if data:
                    os.write(2, data)


def read(path: str | os.PathLike, *, as_float: bool = False, unassociated_alpha: bool = False,
         name: str | None = None) -> Image:
    """Decode ``path`` whole; raises `ImageReadError` naming ``name`` (default: ``path``) when the
    file is missing, empty, not 2D, or OpenImageIO reports any decode error. ``as_float``: float32
    texels (integer files as UNORM in [0, 1]); else the stored type. ``unassociated_alpha``: keep
    stored (straight) colour where alpha < 1."""
    import OpenImageIO as oiio  # lazy: start-up

    local = os.fspath(path)
    shown = name or local
    if not os.path.isfile(local):
        raise ImageReadError(f"{shown}: texture file not found")
    if os.path.getsize(local) == 0:
        raise ImageReadError(f"{shown}: the file is empty (0 bytes)")
    config = oiio.ImageSpec()
    if unassociated_alpha:
        config.attribute("oiio:UnassociatedAlpha", 1)
    ok = [True]
    with _native_stderr(ok):
        inp = oiio.ImageInput.open(local, config)
        if inp is None:
            ok[0] = False
            raise ImageReadError(f"{shown}: cannot read image ({_why(oiio.geterror(), shown, local)})")
        try:
            spec = inp.spec()
            if spec.width < 1 or spec.height < 1 or spec.nchannels < 1 or spec.depth > 1:
                ok[0] = False
                raise ImageReadError(f"{shown}: not a 2D image ({spec.width}x{spec.height}x{spec.depth}, "
                                     f"{spec.nchannels} ch)")
            if spec.width * spec.height > MAX_TEXELS or spec.nchannels > MAX_CHANNELS:
                ok[0] = False  # a damaged header can claim any size: refuse before allocating it
                raise ImageReadError(f"{shown}: the header claims {spec.width}x{spec.height} texels of "
                                     f"{spec.nchannels} channel(s), beyond 16384x16384x{MAX_CHANNELS}")
            data = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT if as_float else oiio.UNKNOWN)
            error = inp.geterror() if inp.has_error else ""
            if data is None or error:
                ok[0] = False
                raise ImageReadError(f"{shown}: cannot read image ({_why(error or oiio.geterror(), shown, local)})")
            stored = str(spec.format)
            names = tuple(n.upper() for n in spec.channelnames)
        finally:
            inp.close()
            oiio.geterror()  # leave no stale global error behind for the next reader
    pixels = np.asarray(data).reshape(spec.height, spec.width, spec.nchannels)
    return Image(pixels, names, stored)


def probe(path: str | os.PathLike) -> tuple[int, int, int, str] | None:
    """(width, height, channels, stored base type) from the header, or None when it cannot be
    opened (the decoder's own complaint is not printed: `read` reports the file)."""
    import OpenImageIO as oiio  # lazy: start-up

    with _native_stderr([False]):
        inp = oiio.ImageInput.open(os.fspath(path))
        if inp is None:
            oiio.geterror()
            return None
        try:
            spec = inp.spec()
            return spec.width, spec.height, spec.nchannels, str(spec.format)
        finally:
            inp.close()
            oiio.geterror()


_SLOT = {"r": 0, "g": 1, "b": 2, "a": 3, "x": 0, "y": 1, "z": 2, "w": 3}


def channel_index(names: tuple[str, ...], letter: str, path: str) -> int:
    """The file channel (of a file whose channels are ``names``) that feeds a requested letter
    (grey replicates into r, g, b; a is the alpha channel)."""
    n = len(names)
    alpha = names.index("A") if "A" in names else None
    slot = _SLOT[letter]
    if slot == 3:
        if alpha is not None:
            return alpha
        if n >= 4:
            return 3
    else:
        colour = [i for i in range(n) if i != alpha]
        if len(colour) == 1:
            return colour[0]
        if slot < len(colour):
            return colour[slot]
    raise MissingChannel(f"{path}: has {n} channel(s) ({','.join(names)}); cannot read channel {letter!r}")
