"""``bcfpipe verify``: check exported neural materials end to end, through the real GLSL decoder.

For every material (one exported folder, or every material of a build) the checks are:

``files``      material.json agrees with the DDS headers (size, mip count, BC6H signedness) and the
               weight record (dimensions, output count); every block uses the declared BC6H mode.
``integrity``  SHA-256 of each file against material.json's ``sha256`` (the exporter records them);
               "not recorded" for a material.json without them.
``weights``    the fp16 record the runtime reads (the material's weights.bin, or the build's combined
               buffer at the material's offset) holds exactly the values of decoder.onnx.
``openimageio`` OpenImageIO reads every mip of every DDS to the same fp16 bits as bcfpipe.bc6h.decode.
``classic``    a layout's classic textures (--layout auto): each DDS agrees with material.json (format,
               size, full mip chain, or in a mip split the levels that serve s < split); texture2ddecoder
               decodes every BC1/BC4/BC5 mip to the same 8-bit values as bcfpipe's own decoder
               (bcfpipe.formats.s3tc), and OpenImageIO to within 2 (BC1) or 1 (BC4/BC5) 8-bit steps
               (its palettes round differently); a BC7 texture (a repacked group) texture2ddecoder
               and OpenImageIO decode bit for bit as bcfpipe.bc7 does; a BC6H_UF16 one (an HDR colour group) OpenImageIO
               (bcdec) to the same fp16 bits as bcfpipe.bc6h, as Mesa does (texture2ddecoder 1.0.6
               misreads BC6H mode 2's endpoints, so it is not asked). A material with classic
               outputs only has no other check but ``integrity``.
``glsl``       glsl/bcf_decode.comp, run through OpenGL (moderngl on EGL: the GPU driver, or Mesa
               llvmpipe), against an independent path: features sampled in numpy/torch from the DDS
               decoded by bcfpipe.bc6h.decode (bcfpipe.model.sampling conventions) fed to decoder.onnx
               through onnxruntime. Sampled at a grid of (u, v, s) with texel centres and edges of
               every level of every layer, uv across and far beyond the borders (repeat / clamp),
               s < 0 (magnification), integer and fractional s, s past every layer's last mip, and
               the runtime extremes: uv +-1e4, s up to +-1e30 and +-inf, and the derivative path
               (bcfDecodeGrad) with zero, tiny, huge and infinite derivatives.

Exit codes (verify_cli): 0 all checks passed, 1 a check failed, 2 bad input or no OpenGL.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from bcfpipe.bc6h import mode10
from bcfpipe.bc6h import decode as bc6h_decode
from bcfpipe.bc7 import anymode, mode6
from bcfpipe.bc7 import decode as bc7_decode
from bcfpipe.formats import dds
from bcfpipe.formats import material as mf
from bcfpipe.formats import manifest as mfst
from bcfpipe.formats.bcn import FORMAT_OF, ClassicFormat, decode_levels
from bcfpipe.formats.digest import sha256_file
from bcfpipe.export import writer as E
from bcfpipe.formats.vocabulary import Status
from bcfpipe.model.decoder import ONNX_INPUT, ONNX_OUTPUT, from_bytes
from bcfpipe.verify.constants import check_constants
from bcfpipe.verify.glsl import GLRuntime, GLUnavailable, MaterialDesc
from bcfpipe.verify.points import CATEGORIES, gradient_points, lod_from_grad, verification_points
from bcfpipe.verify.sources import SourceNotFound, check_sources, root_layers
from bcfpipe.verify.targets import Target, VerifyInputError, find_targets
from bcfpipe.verify.tolerance import FILTER_BITS, TARGET, filter_error, output_tolerance
from bcfpipe.verify.vulkan import VulkanRuntime, VulkanUnavailable


@dataclass
class Check:
    name: str
    passed: bool | None  # None: skipped / not applicable
    detail: str

    def to_dict(self) -> dict:
        return {"name": self.name, "passed": self.passed, "detail": self.detail}


@dataclass
class MaterialReport:
    """One material's checks. ``shares``: the material whose files it shares (a shared texture set),
    checked once, under that material's name; its checks are repeated here."""

    name: str
    folder: str
    checks: list[Check] = field(default_factory=list)
    channels: list[dict] = field(default_factory=list)
    categories: list[dict] = field(default_factory=list)
    n_points: int = 0
    input_error: str | None = None
    shares: str | None = None

    @property
    def passed(self) -> bool:
        return self.input_error is None and all(c.passed is not False for c in self.checks)

    def to_dict(self) -> dict:
        return {"name": self.name, "folder": self.folder, "passed": self.passed, "input_error": self.input_error,
                "checks": [c.to_dict() for c in self.checks], "n_points": self.n_points,
                "channels": self.channels, "categories": self.categories, "shares": self.shares}

    def sharing(self, name: str, extra: Sequence[Check] = ()) -> "MaterialReport":
        """The report of ``name``, which shares this material's files: its checks (not its error
        tables), then ``extra`` (its own constants)."""
        return MaterialReport(name, self.folder, [*self.checks, *extra], input_error=self.input_error,
                              shares=self.name)


@dataclass(frozen=True)
class VerifyEvent:
    """What `verify` reports as it goes, to its ``progress`` callback: ``start`` once the OpenGL
    runtime is up (its ``renderer``, None without GLSL; the ``tolerance`` as `Report` has it;
    ``total`` materials with files), ``check`` before each check of a ``material`` (the folded
    constants: one ``constants`` check of the whole build), ``done`` with each material's
    ``report``. The command line prints the report and its heartbeat from these."""

    kind: str  # start, check, done
    material: str = ""
    check: str = ""
    report: MaterialReport | None = None
    renderer: dict | None = None
    tolerance: dict | None = None
    total: int = 0
    vulkan: dict | None = None  # the Vulkan device's info with --runtime vulkan


VerifyProgress = Callable[[VerifyEvent], None]


def check_files(m: MaterialDesc) -> tuple[Check, list[dds.DdsTexture]]:
    problems, texs = [], []
    for i, path in enumerate(m.layer_files):
        try:
            t = dds.read(path)
        except dds.DdsError as e:
            raise VerifyInputError(str(e)) from None
        texs.append(t)
        layer = m.file.layers[i]
        if t.mip_count != m.mip_counts[i]:
            problems.append(f"{path.name}: {t.mip_count} mips, material.json says {m.mip_counts[i]}")
        if (t.width, t.height) != (layer.resolution, layer.resolution):
            problems.append(f"{path.name}: {t.width}x{t.height}, material.json says {layer.resolution}")
        if t.signed != m.signed or t.is_bc7 != m.bc7:
            problems.append(f"{path.name}: {t.format_name}, material.json says "
                            f"{'bc7' if m.bc7 else 'signed=' + str(m.signed)}")
        if m.bc7:
            any_mode = layer.blocks == mf.ANY_BC7_MODE
            for k, (blocks, w, h) in enumerate(t.levels):
                bad = int((anymode.block_modes(blocks) == 8).sum() if any_mode else (~mode6.is_mode6(blocks)).sum())
                if bad:
                    problems.append(f"{path.name} mip {k}: {bad} block(s) " +
                                    ("in the reserved BC7 mode 8" if any_mode else "not in the declared BC7 mode 6"))
        elif m.file.bc6h.block_mode == mode10.DESCRIPTION:
            for k, (blocks, w, h) in enumerate(t.levels):
                bad = int((~mode10.is_mode10(blocks)).sum())
                if bad:
                    problems.append(f"{path.name} mip {k}: {bad} block(s) not in the declared mode "
                                    f"{mode10.MODE_VALUE:05b}")
    try:
        data = m.weights_file.read_bytes()
        w, size = from_bytes(data, m.weight_offset)
    except (OSError, ValueError) as e:
        raise VerifyInputError(f"{m.weights_file}: {e}") from None
    n_in, hidden, n_out = w.dims
    if n_in != sum(layer.channels for layer in m.file.layers) or n_out != m.n_out:
        problems.append(f"weight record is {n_in}-{hidden}-{n_out}, material.json has {m.n_out} outputs")
    if m.file.mlp.n_hidden != hidden:
        problems.append(f"weight record has {hidden} hidden units, material.json says {m.file.mlp.n_hidden}")
    return Check("files", not problems, "; ".join(problems) or
                 f"{len(texs)} {'BC7 (mode 6)' if m.bc7 else 'BC6H'} layers"
                 f"{'' if m.bc7 else ' (signed)' if m.signed else ' (unsigned)'}, "
                 f"mips {list(m.mip_counts)}, decoder {n_in}-{hidden}-{n_out}"), texs


def check_integrity(t: Target) -> Check:
    m = t.desc
    recorded = dict(m.file.sha256 or {})
    if not recorded:
        return Check("integrity", None, "no SHA-256 recorded (material.json has no 'sha256')")
    bad = []
    for name, hexdigest in sorted(recorded.items()):
        path = m.folder / name
        if not path.is_file():
            bad.append(f"{name} missing")
        elif sha256_file(path) != str(hexdigest).lower():
            bad.append(f"{name} differs from its recorded SHA-256")
    return Check("integrity", not bad, "; ".join(bad) or f"{len(recorded)} files match their SHA-256")


def check_weights_onnx(m: MaterialDesc) -> Check:
    """The record the runtime reads == decoder.onnx's initializers, value for value."""
    import onnx  # lazy: start-up
    from onnx import numpy_helper  # lazy: start-up

    w, _ = from_bytes(m.weights_file.read_bytes(), m.weight_offset)
    try:
        model = onnx.load(str(m.folder / m.file.onnx.file))
    except Exception as e:  # noqa: BLE001
        raise VerifyInputError(f"{m.folder / m.file.onnx.file}: {e}") from None
    inits = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    bad = []
    for name, arr in zip(("W1", "b1", "W2", "b2", "out_scale", "out_bias", "log_gain"), w.arrays()):
        o = inits.get(name)
        if o is None or o.shape != arr.shape:
            bad.append(f"{name}: missing or shaped {None if o is None else o.shape} in decoder.onnx")
            continue
        diff = int((o.astype(np.float32) != arr).sum())
        if diff:
            bad.append(f"{name}: {diff} value(s) differ")
    if w.log_gain is None and "log_gain" in inits:
        bad.append("log_gain: decoder.onnx expands HDR channels, the weight record (v1) does not")
    if m.weights_file != m.folder / m.file.mlp.weights:
        own = m.folder / m.file.mlp.weights
        if own.is_file():
            w_own, _ = from_bytes(own.read_bytes(), m.file.mlp.offset)
            if len(w.arrays()) != len(w_own.arrays()) or any(
                    (a != b).any() for a, b in zip(w.arrays(), w_own.arrays())):
                bad.append(f"record at byte {m.weight_offset} of {m.weights_file.name} differs from {own}")
    where = f"{m.weights_file.name}@{m.weight_offset}"
    return Check("weights", not bad, "; ".join(bad) or f"{where}: all fp16 values equal decoder.onnx's")


def check_openimageio(texs: Sequence[dds.DdsTexture], files: Sequence[Path]) -> Check:
    """Every mip as OpenImageIO's DDS reader decodes it == our spec decoder's, bit for bit (BC6H
    halves; BC7 8-bit values)."""
    try:
        import OpenImageIO as oiio  # lazy: start-up
    except ImportError as e:
        return Check("openimageio", False, f"OpenImageIO is not importable ({e})")
    bad, n_levels = [], 0
    for tex, path in zip(texs, files):
        inp = oiio.ImageInput.open(str(path))
        if inp is None:
            bad.append(f"{path.name}: OpenImageIO cannot open it ({oiio.geterror()})")
            continue
        try:
            for k, (blocks, w, h) in enumerate(tex.levels):
                if not inp.seek_subimage(0, k):
                    bad.append(f"{path.name}: OpenImageIO has no mip {k}")
                    break
                spec = inp.spec()
                img = inp.read_image(format="uint8" if tex.is_bc7 else "half")
                if img is None or (spec.width, spec.height) != (w, h):
                    bad.append(f"{path.name} mip {k}: OpenImageIO read failed or size differs")
                    continue
                if tex.is_bc7:
                    theirs = np.asarray(img).reshape(h, w, -1)[..., :4]
                    ours = np.rint(bc7_decode(blocks, w, h) * 255.0).astype(np.uint8)  # value / 255 back to bytes
                else:
                    theirs = np.ascontiguousarray(np.asarray(img).reshape(h, w, -1)[..., :3]).view(np.uint16)
                    ours = bc6h_decode(blocks, w, h, signed=tex.signed).view(np.uint16)
                diff = int((theirs != ours).sum())
                n_levels += 1
                if diff:
                    bad.append(f"{path.name} mip {k}: {diff} value(s) differ")
            if inp.seek_subimage(0, tex.mip_count):
                bad.append(f"{path.name}: OpenImageIO sees more than {tex.mip_count} mips")
        finally:
            inp.close()
    return Check("openimageio", not bad, "; ".join(bad) or f"{n_levels} mip levels bit-identical")


# OpenImageIO (bcdec) rounds the interpolated BC palettes differently from quicktex and
# texture2ddecoder (which agree bit for bit): measured at most 2 8-bit steps for BC1's 565 colours
# and 1 for BC4/BC5. Hardware decoders differ among themselves in the same way.
OIIO_STEPS = {"bc1": 2, "bc4": 1, "bc5": 1, "bc7": 0}  # BC7's interpolation is exact integer arithmetic


def check_classic(m: MaterialDesc) -> Check:
    """A layout's classic textures: headers against material.json, and three decoders agreeing."""
    import OpenImageIO as oiio  # lazy: start-up

    bad, n_levels, exact = [], 0, True
    try:
        import texture2ddecoder as t2d  # lazy: start-up
    except ImportError:
        t2d, exact = None, False
    for c in m.file.classic:
        path = m.folder / c.file
        try:
            tex = dds.read(path)
        except dds.DdsError as e:
            raise VerifyInputError(str(e)) from None
        if (tex.dxgi_format, tex.width, tex.height, tex.mip_count) != (c.dxgi_format, c.width, c.height, c.mip_count):
            bad.append(f"{c.file}: {tex.format_name} {tex.width}x{tex.height}, {tex.mip_count} mips; material.json "
                       f"says {c.format} {c.width}x{c.height}, {c.mip_count} mips")
            continue
        full = dds.max_mip_count(tex.width, tex.height)
        want = full if m.file.split is None else min(full, max(1, m.file.split + round(c.lod_bias)))
        if tex.mip_count != want:  # a mip split keeps the levels that serve s < split (s + lod_bias)
            bad.append(f"{c.file}: {tex.mip_count} mips, not the " + (f"{want} that serve s < {m.file.split}"
                                                                      if m.file.split is not None else "full chain"))
        fmt = FORMAT_OF.get(tex.dxgi_format)
        if fmt is None:
            bad.append(f"{c.file}: {tex.format_name} is no classic format")
            continue
        ours = [t[..., :c.channels] for t in decode_levels(fmt, tex.levels)]
        inp = oiio.ImageInput.open(str(path))
        if inp is None:
            bad.append(f"{c.file}: OpenImageIO cannot open it ({oiio.geterror()})")
            continue
        try:
            for k, ((blocks, w, h), o) in enumerate(zip(tex.levels, ours)):
                n_levels += 1
                mine = np.rint(o * 255).astype(np.int32)
                # BC6H: t2d misreads mode 2 (OpenImageIO's is exact)
                if t2d is not None and fmt != ClassicFormat.BC6H:
                    pw, ph = (w + 3) // 4 * 4, (h + 3) // 4 * 4
                    dec = {ClassicFormat.BC1: t2d.decode_bc1, ClassicFormat.BC4: t2d.decode_bc4,
                           ClassicFormat.BC5: t2d.decode_bc5, ClassicFormat.BC7: t2d.decode_bc7}[fmt]
                    bgra = np.frombuffer(dec(blocks.tobytes(), pw, ph), np.uint8).reshape(ph, pw, 4)[:h, :w]
                    theirs = bgra[..., [2, 1, 0, 3]][..., :c.channels].astype(np.int32)
                    if (theirs != mine).any():
                        bad.append(f"{c.file} mip {k}: texture2ddecoder differs in {int((theirs != mine).sum())} value(s)")
                if not inp.seek_subimage(0, k):
                    bad.append(f"{c.file}: OpenImageIO has no mip {k}")
                    break
                if fmt == ClassicFormat.BC6H:  # half floats: bit for bit, as the feature layers
                    img = np.asarray(inp.read_image(format="half")).reshape(h, w, -1)[..., :c.channels]
                    differ = int((img.view(np.uint16) != o.astype(np.float16).view(np.uint16)).sum())
                    if differ:
                        bad.append(f"{c.file} mip {k}: OpenImageIO differs in {differ} fp16 value(s)")
                    continue
                img = np.asarray(inp.read_image(format="float")).reshape(h, w, -1)[..., :c.channels]
                step = np.abs(np.rint(img * 255).astype(np.int32) - mine).max()
                if step > OIIO_STEPS[fmt]:
                    bad.append(f"{c.file} mip {k}: OpenImageIO differs by {step} 8-bit steps")
        finally:
            inp.close()
    detail = (f"{len(m.file.classic)} classic texture(s), {n_levels} mip levels: texture2ddecoder "
              f"{'bit-identical' if exact else 'not installed'}, OpenImageIO within 2 (BC1) or 1 (BC4/BC5) "
              "8-bit steps, bit-identical for BC7 and BC6H")
    return Check("classic", not bad, "; ".join(bad) or detail)


def _finite(x) -> float | str:
    """A float for JSON, or 'inf' / '-inf' (strict JSON has no infinities)."""
    x = float(x)
    return x if np.isfinite(x) else str(x)


RUNTIME_LABEL = {"glsl": "GL", "vulkan": "Vulkan"}  # a runtime check's name: what its figures say


@dataclass(frozen=True)
class Expected:
    """What a runtime must give at verify's points: the lod queries (``uv``, ``s``) and the
    derivative ones (``guv``, ``gdx``, ``gdy``) as a runtime takes them; over both, in that order,
    each point's (u, v), lod (the derivative path's as the shader computes it) and category, and
    decoder.onnx's values there with their tolerance. Made once per material, whatever the runtimes."""

    uv: np.ndarray
    s: np.ndarray
    guv: np.ndarray
    gdx: np.ndarray
    gdy: np.ndarray
    all_uv: np.ndarray
    all_s: np.ndarray
    cat: np.ndarray
    ref: np.ndarray
    tol: np.ndarray
    tolerance: float | None


def expected(m: MaterialDesc, em: E.ExportedMaterial, tolerance: float | None, seed: int = 0,
             filter_bits: int = FILTER_BITS) -> Expected:
    """decoder.onnx fed features sampled in numpy from the DDS at verify's points, and the
    tolerance there (derived from the material, or ``tolerance`` fixed)."""
    level_sizes = [[(lv.shape[1], lv.shape[0]) for lv in layer] for layer in em.levels]
    uv, s, cat = verification_points(m, level_sizes, seed)
    guv, gdx, gdy = gradient_points(m.ref_size, seed)
    # the derivative path: the reference takes the shader's fp32 lod, which may sit anywhere
    exact_lods = np.concatenate([np.ones(len(uv)), np.zeros(len(guv))])
    all_uv, all_s = np.concatenate([uv, guv]), np.concatenate([s, lod_from_grad(gdx, gdy, m.ref_size)])
    cat = np.concatenate([cat, np.full(len(guv), CATEGORIES.index("derivatives"))])
    feats = E.sample_exported_features(em, all_uv, all_s)
    ref = E.onnx_session(em).run([ONNX_OUTPUT], {ONNX_INPUT: feats})[0]
    if tolerance is None:
        fe = filter_error(em.levels, em.lod_biases, all_uv, all_s, em.wrap, filter_bits, exact_lods,
                          unorm8=em.desc.features == "bc7")
        tol = output_tolerance(em.weights, em.kinds, feats, fe, ref)
    else:
        tol = np.full(ref.shape, float(tolerance))
    return Expected(uv, s, guv, gdx, gdy, all_uv, all_s, cat, ref, tol, tolerance)


def check_glsl(rt, m: MaterialDesc, ex: Expected, name: str = "glsl") -> tuple[Check, list[dict], list[dict], int]:
    """bcf_decode.comp on ``rt`` (a `GLRuntime`, or with ``name`` "vulkan" a
    `bcfpipe.verify.vulkan.VulkanRuntime`) against decoder.onnx at the verification points."""
    label = RUNTIME_LABEL[name]
    gm = rt.load(m)
    try:
        gl = np.concatenate([rt.decode(gm, ex.uv, ex.s), rt.decode_grad(gm, ex.guv, ex.gdx, ex.gdy)])
    finally:
        rt.unload(gm)
    uv, s, cat, ref, tol, tolerance = ex.all_uv, ex.all_s, ex.cat, ex.ref, ex.tol, ex.tolerance
    if gl.shape != ref.shape:
        return Check(name, False, f"{label} gives {gl.shape[1]} channels, ONNX {ref.shape[1]}"), [], [], len(uv)
    err = np.abs(gl.astype(np.float64) - ref.astype(np.float64))
    err = np.where(np.isnan(err), np.inf, err)  # a NaN from GL (invalid record) always fails
    names = [o.name for o in m.outputs]
    channels = []
    for c in range(ref.shape[1]):
        worst = int(np.argmax(err[:, c]))
        over = int((err[:, c] > tol[:, c]).sum())
        channels.append({"name": names[c] if c < len(names) else f"ch{c}", "max_abs": float(err[:, c].max()),
                         "mean_abs": float(err[:, c].mean()), "max_tolerance": float(tol[:, c].max()),
                         "mean_tolerance": float(tol[:, c].mean()), "over_tolerance": over,
                         "worst": {"u": float(uv[worst, 0]), "v": float(uv[worst, 1]), "s": _finite(s[worst]),
                                   "category": CATEGORIES[cat[worst]]},
                         "passed": over == 0})
    categories = []
    for k, category in enumerate(CATEGORIES):
        sel = cat == k
        if sel.any():
            categories.append({"category": category, "n": int(sel.sum()), "max_abs": float(err[sel].max()),
                               "mean_abs": float(err[sel].mean()),
                               "over_tolerance": int((err[sel] > tol[sel]).sum())})
    n_over = sum(ch["over_tolerance"] for ch in channels)
    mode = "derived bound" if tolerance is None else f"fixed {tolerance:g}"
    detail = (f"{len(uv)} (u, v, s) points x {ref.shape[1]} channels: max |{label} - ONNX| {err.max():.3g} "
              f"(tolerance: {mode}, max {tol.max():.3g})")
    if n_over:
        detail += f"; {n_over} value(s) over tolerance"
    if tolerance is None:
        loose = float((tol > TARGET).mean())
        if loose > 0:  # informational: how sensitive the material is to hardware filtering precision
            detail += f"; bound > {TARGET:g} for {100 * loose:.1f}% of values"
    return Check(name, n_over == 0, detail), channels, categories, len(uv)


@dataclass
class Report:
    path: str
    materials: list[MaterialReport]
    renderer: dict | None
    tolerance: dict
    gl_error: str | None = None  # the runtime that could not be had (OpenGL, or Vulkan), and why
    vulkan: dict | None = None  # the Vulkan device's info with --runtime vulkan
    unavailable: str = "OpenGL"  # which runtime gl_error is about

    @property
    def passed(self) -> bool:
        return self.gl_error is None and all(m.passed for m in self.materials)

    @property
    def exit_code(self) -> int:
        if self.gl_error is not None or any(m.input_error for m in self.materials):
            return 2
        return 0 if self.passed else 1

    def to_dict(self) -> dict:
        return {"path": self.path, "passed": self.passed, "exit_code": self.exit_code, "renderer": self.renderer,
                "vulkan": self.vulkan, "gl_error": self.gl_error, "tolerance": self.tolerance,
                "materials": [m.to_dict() for m in self.materials]}


def verify_target(t: Target, rt: GLRuntime | None, tolerance: float | None = None, seed: int = 0,
                  filter_bits: int = FILTER_BITS, on_check: Callable[[str], None] | None = None,
                  vulkan=None) -> MaterialReport:
    """Every check of one material; ``on_check`` hears each check's name before it runs. With
    ``vulkan`` (a `VulkanRuntime`) the decoder's SPIR-V runs there too, held to decoder.onnx at the
    same points as OpenGL (check ``vulkan``)."""
    m = t.desc
    rep = MaterialReport(m.name, str(m.folder))
    started = on_check or (lambda name: None)
    try:
        if not m.file.neural:  # a layout of classic textures only
            started("integrity")
            rep.checks.append(check_integrity(t))
            started("classic")
            rep.checks.append(check_classic(m))
            return rep
        started("files")
        files, texs = check_files(m)
        rep.checks.append(files)
        started("integrity")
        rep.checks.append(check_integrity(t))
        started("weights")
        rep.checks.append(check_weights_onnx(m))
        started("openimageio")
        rep.checks.append(check_openimageio(texs, m.layer_files))
        if m.file.classic:
            started("classic")
            rep.checks.append(check_classic(m))
        if rt is not None or vulkan is not None:
            started("glsl" if rt is not None else "vulkan")  # the expected values are most of its time
            em = E.load(m.folder)
            em = E.ExportedMaterial(em.desc, em.levels, from_bytes(m.weights_file.read_bytes(), m.weight_offset)[0],
                                    em.onnx_path)
            ex = expected(m, em, tolerance, seed, filter_bits)
        if rt is not None:
            chk, rep.channels, rep.categories, rep.n_points = check_glsl(rt, m, ex)
            rep.checks.append(chk)
        else:
            rep.checks.append(Check("glsl", None, "skipped (--no-glsl)"))
        if vulkan is not None:
            if rt is not None:
                started("vulkan")
            rep.checks.append(check_glsl(vulkan, m, ex, name="vulkan")[0])
    except VerifyInputError as e:
        rep.input_error = str(e)
    except (OSError, KeyError, dds.DdsError) as e:
        rep.input_error = f"{type(e).__name__}: {e}"
    return rep


def constant_checks(root: Path) -> dict[str, Check]:
    """For a build folder, the ``constants`` check of each material with folded constants
    (bcfpipe.verify.constants), by material path, in the manifest's order."""
    if not (root / mfst.FILE).is_file():
        return {}
    return {name: Check("constants", passed, detail) for name, passed, detail in check_constants(root, mfst.read(root))}


def build_order(root: Path) -> list[str]:
    """The built and constant materials of a build folder in its manifest's order ([] for a
    material folder or a folder of them: the order they are found in)."""
    if not (root / mfst.FILE).is_file():
        return []
    return [m.path for m in mfst.read(root).materials if m.status in (Status.BUILT, Status.CONSTANT)]


class InOrder:
    """Material reports handed on (``emit``) in ``order`` as soon as every one before them is
    done, whatever order their texture sets are checked in; reports of names not in ``order``
    go as they come."""

    def __init__(self, order: Sequence[str], emit: Callable[[MaterialReport], None]):
        self.order, self.emit = list(order), emit
        self.waiting: dict[str, MaterialReport] = {}
        self.out: list[MaterialReport] = []

    def add(self, reports: Sequence[MaterialReport]) -> None:
        for rep in reports:
            if rep.name in self.order:
                self.waiting[rep.name] = rep
            else:
                self._emit(rep)
        while self.order and self.order[0] in self.waiting:
            self._emit(self.waiting.pop(self.order.pop(0)))

    def _emit(self, rep: MaterialReport) -> None:
        self.out.append(rep)
        self.emit(rep)

    def finish(self) -> list[MaterialReport]:
        """Every report, in order (any the order named but never came are left out)."""
        for name in self.order:
            if name in self.waiting:
                self._emit(self.waiting.pop(name))
        return self.out


def target_reports(t: Target, checked: MaterialReport, constants: dict[str, Check]) -> list[MaterialReport]:
    """One report per material that uses ``t``'s files: ``checked`` for the first, a report that
    shares its checks for each other; each with its own constants check, taken out of ``constants``."""
    names = t.aliases or [checked.name]
    shared = list(checked.checks)
    if names[0] in constants:
        checked.checks.append(constants.pop(names[0]))
    others = [MaterialReport(checked.name, checked.folder, shared, input_error=checked.input_error)
              .sharing(name, [constants.pop(name)] if name in constants else []) for name in names[1:]]
    return [checked, *others]


def verify(path: str | os.PathLike, tolerance: float | None = None, glsl: bool = True, seed: int = 0,
           filter_bits: int = FILTER_BITS, runtime: GLRuntime | None = None,
           progress: VerifyProgress | None = None, vulkan: bool = False) -> Report:
    """Verify every material under ``path``; raises VerifyInputError when there is nothing to verify.
    ``progress`` hears `VerifyEvent`s as it goes (nothing when OpenGL is unavailable). ``vulkan``:
    run the decoder on Vulkan too (`bcfpipe.verify.vulkan`; no Vulkan device: exit 2, as no OpenGL)."""
    targets = find_targets(path)
    for root in root_layers(path):  # a build folder: its stage must still reach the scene it was built over
        try:
            check_sources(root)
        except SourceNotFound as e:
            raise VerifyInputError(str(e)) from None
    tol_info = {"mode": "derived" if tolerance is None else "fixed", "filter_bits": filter_bits,
                "target": TARGET}
    if tolerance is not None:
        tol_info["value"] = tolerance
    rt, own = runtime, False
    if glsl and rt is None:
        try:
            rt, own = GLRuntime(), True
        except GLUnavailable as e:
            return Report(str(path), [], None, tol_info, gl_error=str(e))
    vk = None
    if vulkan:
        try:
            vk = VulkanRuntime()
        except VulkanUnavailable as e:
            if own:
                rt.release()
            return Report(str(path), [], None, tol_info, gl_error=str(e), unavailable="Vulkan")
    tell = progress or (lambda ev: None)
    try:
        renderer = rt.info if rt is not None else None
        tell(VerifyEvent("check", check="constants"))
        constants = constant_checks(Path(path))
        users = {name for t in targets for name in t.aliases}
        total = sum(len(t.aliases) or 1 for t in targets) + sum(name not in users for name in constants)
        tell(VerifyEvent("start", renderer=renderer, tolerance=tol_info, total=total,
                         vulkan=vk.info if vk is not None else None))
        ordered = InOrder(build_order(Path(path)), lambda rep: tell(VerifyEvent("done", rep.name, report=rep)))
        for t in targets:
            name = t.desc.name
            checked = verify_target(t, rt if glsl else None, tolerance, seed, filter_bits,
                                    on_check=lambda check, name=name: tell(VerifyEvent("check", name, check)),
                                    vulkan=vk)
            ordered.add(target_reports(t, checked, constants))
        # a constant material: nothing but its values
        ordered.add([MaterialReport(name, str(path), [check]) for name, check in constants.items()])
        return Report(str(path), ordered.finish(), renderer, tol_info, vulkan=vk.info if vk is not None else None)
    finally:
        if own:
            rt.release()
        if vk is not None:
            vk.release()
