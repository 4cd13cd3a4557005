"""JSON Schemas of material.json and manifest.json, derived from their records.

The records (:mod:`bcfpipe.formats.material`, :mod:`bcfpipe.formats.manifest`) give the keys and
types; :data:`DESCRIPTIONS` says what each key means. ``python -m bcfpipe.formats.schema`` writes
them into bcfpipe/schemas/ (material, manifest and report .schema.json); a test checks that the committed
files are what this module generates, and that every file bcfpipe writes validates against them.
"""
from __future__ import annotations

import dataclasses
import json
import sys
import types
import typing
from pathlib import Path
from typing import Any

from bcfpipe.formats import manifest, material, report
from bcfpipe.formats.record import field_hints, key_order
from bcfpipe.formats.vocabulary import Status
from bcfpipe.resources import SCHEMA_DIR

BASE_URI = "https://bcfpipe.dev/schemas/"

# (record, key) -> meaning. Every key of every record has one (a test checks).
DESCRIPTIONS: dict[tuple[str, str], str] = {
    # ---------------------------------------------------------------- material.json
    ("MaterialFile", "format"): "Always \"bcfpipe-material\".",
    ("MaterialFile", "format_version"): "8 when a classic normal is stored as slopes (an output's encoding), else 7 when the addressing is per axis (sampling.wrap_s / wrap_t: the axes "
                                        "differ or one mirrors), else 6 with more than four layers (a T_0 of two or three layers of principal "
                                        "components), else 5 when a layer is in any BC7 mode, else 4 for a mip-split "
                                        "layout (split), else 3. Version of this contract; a reader refuses versions "
                                        "it does not know.",
    ("MaterialFile", "bcfpipe_version"): "The bcfpipe release that wrote the file.",
    ("MaterialFile", "layers"): "The feature textures T_0..T_3 (with a T_0 of several layers: T0, T0b, T0c, then "
                                "T1..T3), in MLP input order.",
    ("MaterialFile", "bc6h"): "How the feature textures are compressed, when they are BC6H (the default).",
    ("MaterialFile", "bc7"): "How the feature textures are compressed, when they are BC7 (--features bc7); "
                             "exactly one of bc6h and bc7 is present.",
    ("MaterialFile", "sampling"): "How a decoder samples the feature textures (the paper's section 5.2).",
    ("MaterialFile", "reference"): "The source texture set the material reproduces.",
    ("MaterialFile", "mlp"): "The decoder network and where its fp16 weights are.",
    ("MaterialFile", "outputs"): "Decoded channels in output order, normal z included after normal y.",
    ("MaterialFile", "onnx"): "The decoder as an ONNX model (features in, post-processed channels out).",
    ("MaterialFile", "training"): "How the material was trained (informative; times vary between runs).",
    ("MaterialFile", "classic"): "Classic BC textures that some outputs read directly (a layout's classic groups, "
                                 "--layout auto); empty when every output comes from the MLP.",
    ("MaterialFile", "split"): "A mip-split layout only: the first reference mip s that the MLP serves. Its outputs "
                               "(source \"split\") read their classic texture up to s = split - 1, the MLP from "
                               "s = split, and (1 - w) * classic + w * MLP between, w = clamp(s - split + 1, 0, 1).",
    ("MaterialFile", "sha256"): "SHA-256 (hex) of every other file of the material, by file name.",
    ("ClassicTexture", "file"): "DDS file name, relative to the material folder.",
    ("ClassicTexture", "dxgi_format"): "71 (BC1_UNORM), 80 (BC4_UNORM), 83 (BC5_UNORM), 95 (BC6H_UF16: a float colour "
                                       "beyond 1, linear) or 98 (BC7_UNORM: a group repacked at equal bytes).",
    ("ClassicTexture", "format"): "The DXGI format's name.",
    ("ClassicTexture", "width"): "Width of mip 0 in texels.",
    ("ClassicTexture", "height"): "Height of mip 0 in texels.",
    ("ClassicTexture", "mip_count"): "Mips stored: down to 1x1, or in a mip-split layout those that serve s < split "
                                     "(the lod clamps to the last).",
    ("ClassicTexture", "lod_bias"): "Added to s before sampling: log2 of this texture's width over the reference's.",
    ("ClassicTexture", "channels"): "Channels the outputs read (BC1: 3, BC4: 1, BC5: 2, BC6H: 3; BC7: 3 or 4); texels "
                                    "are UNORM in "
                                    "[0, 1], BC6H's unsigned half floats (the source's linear values).",
    ("ClassicTexture", "slots"): "Per texel channel, the index in outputs of the output it stores, when a channel is "
                                 "stored in more than one slot (a colour whose source repeats a channel, kept in the "
                                 "slots a UsdUVTexture's rgb reads); absent when every channel is stored once.",
    ("Layer", "file"): "DDS file name, relative to the material folder.",
    ("Layer", "resolution"): "Width and height of mip 0 in texels (square, a power of two).",
    ("Layer", "mip_count"): "Number of mips stored (down to 4x4, the BC6H block size).",
    ("Layer", "lod_bias"): "Added to the level of detail s before sampling this layer: s_i = s + lod_bias.",
    ("Layer", "channels"): "Feature channels: 3 (BC6H, RGB) or 4 (BC7, RGBA); the MLP reads them in order.",
    ("Layer", "blocks"): "\"any BC7 mode\" when this layer's blocks may use every BC7 mode (a T_0 of the set's "
                         "principal components, encoded once); absent: every block is in the bc7 or bc6h record's "
                         "mode. A decoder samples both alike (material.json version 5).",
    ("BC7", "dxgi_format"): "98 (BC7_UNORM).",
    ("BC7", "block_mode"): "The one BC7 mode every block uses (bcfpipe.bc7.mode6); a texel is its 8-bit value / 255.",
    ("BC6H", "dxgi_format"): "95 (BC6H_UF16) or 96 (BC6H_SF16).",
    ("BC6H", "signed"): "Whether the features use the signed BC6H format.",
    ("BC6H", "block_mode"): "The one BC6H mode every block uses (bcfpipe.bc6h.mode10).",
    ("Sampling", "addressing"): "Texture addressing of every layer and classic texture, both axes alike: repeat "
                                "or clamp (to edge). Absent when the axes differ or one mirrors: then wrap_s and "
                                "wrap_t (version 7).",
    ("Sampling", "wrap_s"): "Addressing along u (S, a UsdUVTexture's wrapS) of every layer and classic texture: "
                            "repeat, clamp (to edge) or mirror (GL_MIRRORED_REPEAT); with wrap_t, instead of "
                            "addressing (version 7).",
    ("Sampling", "wrap_t"): "Addressing along v (T, a UsdUVTexture's wrapT): repeat, clamp or mirror.",
    ("Sampling", "filter"): "Texture filtering a decoder must use.",
    ("Sampling", "uv"): "Texture coordinate convention.",
    ("Sampling", "lod"): "How the level of detail is chosen.",
    ("Reference", "width"): "Source width in texels; s = 0 samples at this density.",
    ("Reference", "height"): "Source height in texels.",
    ("Reference", "mip_count"): "Mips of the source's full chain (down to 1x1).",
    ("Mlp", "weights"): "File holding the fp16 weight record, relative to the material folder.",
    ("Mlp", "offset"): "Byte offset of the record in that file.",
    ("Mlp", "size_bytes"): "Byte size of the record.",
    ("Mlp", "n_in"): "Inputs: the layers' channels in order (12 for BC6H, 16 for BC7).",
    ("Mlp", "n_hidden"): "Hidden units.",
    ("Mlp", "n_out"): "MLP outputs (normal z excluded).",
    ("Mlp", "activation"): "Hidden-layer activation.",
    ("Mlp", "precision"): "Storage precision of the weights.",
    ("Mlp", "record"): "Layout of the weight record (bcfpipe.model.decoder).",
    ("Mlp", "input_order"): "Feature order of the MLP input, layer.channel.",
    ("Mlp", "out_scale"): "Per output: y = out_scale * mlp(x) + out_bias, before clamping to its range.",
    ("Mlp", "out_bias"): "Per output: see out_scale.",
    ("Output", "name"): "semantic.component, e.g. albedo.r.",
    ("Output", "semantic"): "The texture-set semantic (albedo, normal, roughness, ...).",
    ("Output", "component"): "The component within the semantic: r, g, b for colour, x, y, z for normals, "
                             "the source channel letter for scalars.",
    ("Output", "kind"): "color, normal or scalar: how the output is post-processed and measured.",
    ("Output", "usd_target"): "The UsdPreviewSurface input (and component) it feeds; null if none.",
    ("Output", "range"): "Output range [lo, hi]; decoded values are clamped to it.",
    ("Output", "source_channel"): "Channel index in the source image; null when reconstructed.",
    ("Output", "source_format"): "Stored texel type of the source image (OpenImageIO base type, e.g. uint8); "
                                 "null when reconstructed.",
    ("Output", "reconstructed"): "True for normal z = sqrt(1 - x^2 - y^2), computed, not learned.",
    ("Output", "value_scale"): "The source value is decoded * value_scale + value_bias: 1 and 0 for data in "
                               "[0, 1]; hi - lo and lo for a float channel whose values leave it (HDR, "
                               "negative). Quality figures use hi - lo as the channel's peak.",
    ("Output", "value_bias"): "See value_scale.",
    ("Output", "log_gain"): "Present for HDR channels only (non-negative float colour beyond 1): the MLP "
                            "learns t = log2(1 + v (2^g - 1)) / g of the normalised value v, and the "
                            "decoder returns v = (2^(g t) - 1) / (2^g - 1) after the clamp (weight record "
                            "BCFW v2). Absent: linear, and on every classic output (a classic texture stores "
                            "linear values: HDR colour as BC6H_UF16).",
    ("Output", "source"): "Absent: the decoder's (MLP and post-processing) output; the decoder's outputs are the "
                          "outputs without a source or with source \"split\", in order. \"classic\": read from "
                          "classic texture `texture`, channel `texel_channel`, as texel * texel_scale + texel_bias, "
                          "then clamped to range; a classic normal's z is sqrt(max(0, 1 - x^2 - y^2)). \"split\": "
                          "both, mixed by lod (see split); a split normal's z is the decoder's from s = split on, "
                          "else sqrt(max(0, 1 - x^2 - y^2)) of the mixed x and y.",
    ("Output", "texture"): "Classic and split outputs: index into classic.",
    ("Output", "texel_channel"): "Classic outputs: the texture channel (0 = r); none for a normal's z, which is rebuilt.",
    ("Output", "texel_scale"): "Classic outputs: value = texel * texel_scale + texel_bias (a slope normal: 2m, -m; BC6H: "
                               "1 / value_scale, -value_bias / value_scale, so the source value is the texel).",
    ("Output", "texel_bias"): "Classic outputs: see texel_scale.",
    ("Output", "encoding"): "\"slope\" on a classic or split normal's x, y and z stored as slopes (a layout's classic "
                            "normal, for a UsdUVTexture): x's and y's texel * texel_scale + texel_bias (2m, -m) are "
                            "s_x = x / z and s_y = y / z, unclamped; the normal is (s_x, s_y, 1) normalised, so "
                            "x = s_x / sqrt(1 + s_x^2 + s_y^2) and z = 1 / sqrt(1 + s_x^2 + s_y^2). Absent: x and y "
                            "are the values themselves.",
    ("Onnx", "file"): "ONNX file name, relative to the material folder.",
    ("Onnx", "input"): "Input tensor name: float32 (N, n_in) features.",
    ("Onnx", "output"): "Output tensor name: float32 (N, outputs) channels.",
    ("Onnx", "opset"): "ONNX opset version.",
    ("Training", "profile_resolutions"): "Resolutions of T_0..T_3 (the profile).",
    ("Training", "preset"): "Quality preset (bcfpipe.config.PRESETS).",
    ("Training", "seed"): "Random seed.",
    ("Training", "device"): "Device class that trained it (cpu or cuda): results differ between them.",
    # ---------------------------------------------------------------- manifest.json
    ("Manifest", "format"): "Always \"bcfpipe-build\".",
    ("Manifest", "format_version"): "Version of this contract; a reader refuses versions it does not know.",
    ("Manifest", "bcfpipe_version"): "The bcfpipe release that wrote the file.",
    ("Manifest", "scene"): "The input scene, relative to the build folder.",
    ("Manifest", "root_layer"): "The USD layer to open: the overrides over the untouched scene.",
    ("MaterialReport", "layout"): "--layout auto (the default) or --classic only: what was chosen against BC@R and why (as manifest.json says).",
    ("Material", "layout"): "--layout auto (the default) or --classic only: what was chosen for this material and why.",
    ("LayoutChoice", "chosen"): "The layout shipped: 'neural P', 'neural P + classic G, ...', 'all classic (BC@R)', "
                              "'BC@R with G as BC7' (groups repacked in the same bytes) or 'BC@R below mip k + "
                              "neural T from it' (a mip split).",
    ("LayoutChoice", "classic"): "The channel groups shipped as classic BC textures.",
    ("LayoutChoice", "profile"): "The neural part's profile; null when every output is classic.",
    ("LayoutChoice", "reason"): "Why, in one line.",
    ("LayoutChoice", "size_bytes"): "Bytes of the shipped layout (feature textures, weights, classic textures).",
    ("LayoutChoice", "bc_size_bytes"): "Bytes of BC@R, the classic set at the material's resolution.",
    ("LayoutChoice", "psnr"): "PSNR over all mips of the chosen layout, dB.",
    ("LayoutChoice", "bc_psnr"): "PSNR over all mips of BC@R, dB.",
    ("LayoutChoice", "margin_per_mip_db"): "Per reference mip: the layout's PSNR minus BC@R's, dB.",
    ("LayoutChoice", "worst_margin_db"): "The smallest of margin_per_mip_db over the mips the rule counts (at least 4 texels a side), dB; the floor is -0.5.",
    ("LayoutChoice", "normal_angle_deg"): "The shipped normal map's mean and 99th-percentile angle from the set's, in degrees, at mip 0, as it is read (a classic normal as a UsdPreviewSurface reads it); absent without a normal map.",
    ("Manifest", "overrides_layer"): "The USD layer with the neural-material overrides.",
    ("Manifest", "weights"): "The combined weight buffer (bcfpipe.formats.weights).",
    ("Manifest", "variants"): "Variant selections given on the command line, as [set, value].",
    ("Manifest", "variant_selections"): "Variant selections authored into the root layer.",
    ("Manifest", "all_materials"): "Whether unbound materials were built too (--all-materials).",
    ("Manifest", "options"): "The build's job record (bcfpipe.config.JobOptions) as it writes itself: one key per "
                             "training option, named as its field (--t0-layers: t0_layers), null where not given "
                             "and resolved by the build; not threads or bench_data (how a build ran, not what it "
                             "made). A reader keeps keys it does not know.",
    ("Manifest", "stage"): "Stage metadata copied to the root layer.",
    ("Manifest", "materials"): "Every Material prim of the scene, in stage order.",
    ("Manifest", "jobs"): "Every training job (texture set) the build planned.",
    ("Manifest", "weights_table"): "The records of the combined weights.bin, by index.",
    ("Manifest", "totals"): "Counts, sizes and times over the whole build.",
    ("Manifest", "diagnostics"): "USD composition errors and warnings met while scanning.",
    ("Manifest", "exit_code"): "0 every material built or skipped, 1 a material failed.",
    ("Stage", "up_axis"): "The scene's upAxis.",
    ("Stage", "meters_per_unit"): "The scene's metersPerUnit.",
    ("Stage", "default_prim"): "The scene's defaultPrim path, null if unset.",
    ("VariantSelection", "prim"): "Prim path.",
    ("VariantSelection", "set"): "Variant set name.",
    ("VariantSelection", "value"): "Selected variant.",
    ("Material", "path"): "The Material prim path.",
    ("Material", "aliases"): "Other prim paths (instance proxies) that resolve to the same material.",
    ("Material", "job"): "The job that trains it; null when skipped.",
    ("Material", "status"): "built, constant (every textured input folded to a value; nothing trained), failed or skipped.",
    ("Material", "reason"): "Why it was skipped or failed (a short code or one line); null when built.",
    ("Material", "message"): "What the scan found (human-readable).",
    ("Material", "sources"): "Texture files it reads.",
    ("Material", "targets"): "UsdPreviewSurface input channels the neural material drives.",
    ("Material", "constants"): "Inputs whose texture channels are all constant: the values authored on the surface (connection blocked).",
    ("Material", "folded"): "Source channels that are not decoder outputs: constant or duplicate.",
    ("Material", "metrics"): "Quality of the exported files; null unless built.",
    ("Material", "sizes"): "Bytes on disk; null unless built.",
    ("Material", "outputs"): "Where its files are; null unless built.",
    ("Material", "profile"): "Resolved profile (only when built).",
    ("Material", "resolutions"): "Resolutions of T_0..T_3 (only when built).",
    ("Material", "device"): "torch device its job ran on.",
    ("Material", "warnings"): "Scan warnings about this material.",
    ("MaterialReport", "attempts"): "How many times its job ran, when more than once (its worker died and Ray retried it).",
    ("BuildReport", "executor"): "Where the jobs ran when not in the local process pool: 'ray'.",
    ("Material", "preset"): "Training preset of its job (only when built).",
    ("Material", "target"): "What --target-psnr chose for this material (only with --target-psnr).",
    ("RateControl", "target_psnr"): "The requested PSNR over all mips, dB.",
    ("RateControl", "met"): "Whether the kept training reached it.",
    ("RateControl", "psnr"): "PSNR over all mips of the kept training's exported files, dB.",
    ("RateControl", "profile"): "Profile of the kept training.",
    ("RateControl", "preset"): "Preset of the kept training.",
    ("RateControl", "anchors"): "What predicted: 'probe' (a short training) or 'bench' (--bench-data cells).",
    ("RateControl", "predicted_max"): "Highest predicted PSNR over the candidates after the last attempt, dB.",
    ("RateControl", "seconds"): "Wall time of all attempts, s.",
    ("RateControl", "attempts"): "Every training run, in order.",
    ("RateControl", "notes"): "Why a best-effort setting was trained.",
    ("RateAttempt", "profile"): "Its profile.",
    ("RateAttempt", "preset"): "Its preset.",
    ("RateAttempt", "why"): "probe, predicted (the first choice), climb (after a miss) or best effort (unreachable).",
    ("RateAttempt", "predicted_psnr"): "PSNR predicted before it ran, dB (none for the probe).",
    ("RateAttempt", "psnr"): "PSNR of its exported files, dB.",
    ("RateAttempt", "size_bytes"): "Bytes of its features and weights.",
    ("RateAttempt", "train_seconds"): "Its training time, s.",
    ("Source", "file"): "The file, relative to the build folder, or package.usdz[inner/path].",
    ("Source", "asset_path"): "The asset path as authored in the scene.",
    ("Source", "xxh3_128"): "XXH3-128 of the file's bytes (hex).",
    ("Source", "size_bytes"): "File size in bytes.",
    ("Source", "width"): "Image width.",
    ("Source", "height"): "Image height.",
    ("Source", "channels"): "Image channels.",
    ("Source", "format"): "Stored texel type (OpenImageIO base type, e.g. uint8, half).",
    ("Source", "color_space"): "sourceColorSpace as authored (auto, raw or sRGB).",
    ("Source", "resolved_color_space"): "sRGB or raw, with auto resolved as Hydra does.",
    ("Target", "target"): "UsdPreviewSurface input and component, e.g. diffuseColor.r.",
    ("Target", "input"): "UsdPreviewSurface input.",
    ("Target", "channel"): "Decoder output index that drives it (normal z included); -1 for a constant component, whose value is bias.",
    ("Constant", "target"): "UsdPreviewSurface input and component, e.g. diffuseColor.r.",
    ("Constant", "input"): "UsdPreviewSurface input.",
    ("Constant", "value"): "The value the UsdUVTexture gives: the colour space decoded as Hydra does, then scale and bias; for a texture with no file or a missing one, its fallback component, unscaled (as Hydra).",
    ("Constant", "source"): "Source file of the channel, as in sources; empty when the texture has no readable file and gives its fallback.",
    ("Constant", "source_channel"): "Channel of the source file (r, g, b, a).",
    ("Folded", "source"): "Source file of the channel.",
    ("Folded", "channel"): "Channel of the source file (r, g, b, a).",
    ("Folded", "reason"): "constant (all texels equal within one 8-bit step or fp16 ulp), unread (st not connected: the texture is read at one point, whose value replaces it), no-alpha (the a of a file without alpha: 1, as Hydra reads it) or duplicate (texels identical to another modelled channel).",
    ("Folded", "value"): "The constant's stored value, or the value at the one point read ([0, 1] for integer files), before colour decode, scale and bias.",
    ("Folded", "same_as_source"): "For a duplicate: the file of the channel the decoder outputs instead.",
    ("Folded", "same_as_channel"): "For a duplicate: that file's channel.",
    ("Target", "scale"): "UsdUVTexture scale applied to the decoded value.",
    ("Target", "bias"): "UsdUVTexture bias added after the scale.",
    ("Target", "color_space"): "sRGB or raw: how the decoded value is interpreted.",
    ("Target", "source"): "Source file of the channel, as in sources; null when reconstructed.",
    ("Target", "source_channel"): "Channel of the source file (r, g, b, a); null when reconstructed.",
    ("Metrics", "psnr"): "PSNR in dB over the mips counted in the mean (the headline figure).",
    ("Metrics", "ssim"): "SSIM at mip 0.",
    ("Metrics", "flip"): "FLIP at mip 0 of the colour channels (lower is better); null without colour.",
    ("Metrics", "float_psnr"): "PSNR of the float model before quantization (what BC6H costs).",
    ("Metrics", "detail"): "Per-mip and per-group figures.",
    ("Quality", "psnr"): "PSNR in dB over the mips counted in the mean.",
    ("Quality", "psnr_per_mip"): "PSNR in dB of each mip, mip 0 first.",
    ("Quality", "covered_fraction"): "Share of mip 0's texels that the scene's meshes read (dilated by the filter footprint); absent without a coverage mask.",
    ("Quality", "psnr_covered"): "As psnr, over the covered texels only; absent without a coverage mask.",
    ("Quality", "psnr_per_mip_covered"): "As psnr_per_mip, over the covered texels only; absent without a coverage mask.",
    ("Quality", "psnr_per_group"): "PSNR in dB of each channel group (semantic).",
    ("Quality", "ssim"): "SSIM at mip 0.",
    ("Quality", "ssim_per_group"): "SSIM at mip 0 of each channel group.",
    ("Quality", "flip"): "FLIP at mip 0 of the colour channels.",
    ("Quality", "flip_per_group"): "FLIP at mip 0 of each colour group.",
    ("Quality", "mips_in_mean"): "How many mips, from mip 0, the mean PSNR covers.",
    ("Sizes", "features_bytes"): "Bytes of the four DDS files.",
    ("Sizes", "weights_bytes"): "Bytes of its weight record.",
    ("Sizes", "total_bytes"): "features_bytes + weights_bytes + classic_bytes.",
    ("Sizes", "classic_bytes"): "Bytes of the classic BC textures a --layout auto material ships (C*.dds).",
    ("Sizes", "source_bytes"): "Bytes of the source files it replaces.",
    ("Outputs", "folder"): "Its material folder, relative to the build folder.",
    ("Outputs", "weights_index"): "Index of its record in the combined weights.bin.",
    ("Outputs", "weights_offset"): "Byte offset of its record in the combined weights.bin.",
    ("Outputs", "weights_size"): "Byte size of its record.",
    ("Job", "name"): "Job name: its folder under materials/.",
    ("Job", "materials"): "Material prims it serves.",
    ("Job", "content_hash"): "Hash of its source bytes and settings.",
    ("Job", "status"): "built, failed or \"not run\".",
    ("Job", "reason"): "Why it failed (one line); null when built.",
    ("Job", "device"): "torch device it ran on.",
    ("Job", "weights_index"): "Index of its record in the combined weights.bin; null unless built.",
    ("WeightsRecord", "index"): "Record index (the material id of the paper's section 5.3).",
    ("WeightsRecord", "offset"): "Byte offset of the record.",
    ("WeightsRecord", "size_bytes"): "Byte size of the record.",
    ("WeightsRecord", "n_hidden"): "Hidden units.",
    ("WeightsRecord", "n_out"): "MLP outputs.",
    ("WeightsRecord", "job"): "The job whose decoder it is.",
    ("Totals", "materials"): "Material prims in the scene.",
    ("Totals", "built"): "Materials built.",
    ("Totals", "constant"): "Materials whose textured inputs are all constant: values authored, nothing trained.",
    ("Totals", "failed"): "Materials that failed.",
    ("Totals", "skipped"): "Materials skipped (not modelled).",
    ("Totals", "jobs"): "Jobs planned.",
    ("Totals", "trained"): "Jobs with a trained material (trained by this run or taken from the cache).",
    ("Totals", "features_bytes"): "Bytes of every DDS file.",
    ("Totals", "weights_bytes"): "Bytes of the combined weights.bin.",
    ("Totals", "total_bytes"): "features_bytes + weights_bytes.",
    ("Totals", "source_bytes"): "Bytes of every source file of the scene's modelled materials.",
    # ---------------------------------------------------------------- build --json report
    ("BuildReport", "format"): "Always \"bcfpipe-build-report\".",
    ("BuildReport", "format_version"): "Version of this interface; keys are only ever added.",
    ("BuildReport", "out"): "The output folder, as given (or its default).",
    ("BuildReport", "root_layer"): "The USD layer to open.",
    ("BuildReport", "manifest"): "The build's manifest.json.",
    ("BuildReport", "exit_code"): "0 every material built or skipped, 1 a material failed.",
    ("BuildReport", "verify_exit_code"): "Exit code of `bcfpipe verify` (with --verify only).",
    ("BuildReport", "cache"): "The cache this run used.",
    ("BuildReport", "totals"): "Counts, sizes and times of this run.",
    ("BuildReport", "materials"): "Every Material prim of the scene, in stage order.",
    ("BuildReport", "written"): "Files this run created or replaced in OUT, relative to it (empty for a no-op).",
    ("BuildReport", "depfile"): "The depfile written (--depfile), or null.",
    ("CacheReport", "enabled"): "False with --no-cache.",
    ("CacheReport", "root"): "The cache folder; null when disabled.",
    ("CacheReport", "hits"): "Jobs whose trained material came from the cache.",
    ("CacheReport", "misses"): "Jobs trained by this run.",
    ("CacheReport", "damaged"): "Entries that failed their digest check: discarded and retrained (one line each).",
    ("ReportTotals", "materials"): "Material prims in the scene.",
    ("ReportTotals", "built"): "Materials built.",
    ("ReportTotals", "constant"): "Materials whose textured inputs are all constant: values authored, nothing trained.",
    ("ReportTotals", "failed"): "Materials that failed.",
    ("ReportTotals", "skipped"): "Materials skipped (not modelled).",
    ("ReportTotals", "jobs"): "Jobs planned.",
    ("ReportTotals", "trained"): "Jobs trained by this run (cache misses that built).",
    ("ReportTotals", "cached"): "Jobs taken from the cache.",
    ("ReportTotals", "train_seconds"): "Seconds spent training in this run (sum over jobs).",
    ("ReportTotals", "wall_seconds"): "Wall seconds of this run.",
    ("ReportTotals", "encode_seconds"): "Seconds spent estimating BC@R and its repacks from samples of their blocks and "
                                        "encoding in full what ships, in this run (sum over jobs).",
    ("ReportTotals", "total_bytes"): "Bytes of the feature textures and the combined weights.",
    ("ReportTotals", "written_files"): "Files created or replaced in OUT.",
    ("MaterialReport", "path"): "The Material prim path.",
    ("MaterialReport", "status"): "built, failed or skipped.",
    ("MaterialReport", "reason"): "Why it was skipped or failed; null when built.",
    ("MaterialReport", "job"): "Its job (folder under materials/); null when skipped.",
    ("MaterialReport", "cache"): "hit: its trained material came from the cache; miss: this run trained it; "
                                 "null: skipped, failed before training, or the cache is off.",
    ("MaterialReport", "psnr"): "PSNR in dB of the exported files over the mips counted in the mean; over the texels the scene reads when a coverage mask applied (manifest.json has both).",
    ("MaterialReport", "psnr_per_mip"): "PSNR in dB of each mip, mip 0 first (over the texels read, as psnr).",
    ("MaterialReport", "train_seconds"): "Seconds its material trained (when it was trained, for a hit).",
    ("MaterialReport", "encode_seconds"): "Seconds its layout fit spent estimating BC@R and its BC7 repacks and "
                                          "encoding in full what ships, apart from training (when it was encoded, "
                                          "for a hit); null when it encoded none (all neural).",
    ("MaterialReport", "seconds"): "Wall seconds its job took in this run (0 for a hit found before any worker).",
    ("MaterialReport", "total_bytes"): "Bytes of its feature textures and weight record.",
    ("MaterialReport", "files"): "Its output files, relative to OUT.",
    ("MaterialReport", "folded"): "Source channels that are not decoder outputs (constant or duplicate), as in manifest.json.",
}

ENUMS: dict[tuple[str, str], list] = {
    ("MaterialFile", "format"): [material.FORMAT],
    ("MaterialFile", "format_version"): [material.NO_SPLIT_VERSION, material.SPLIT_VERSION, material.ANY_MODE_VERSION,
                                         material.MANY_LAYERS_VERSION, material.PER_AXIS_VERSION,
                                         material.FORMAT_VERSION],
    ("Manifest", "format"): [manifest.FORMAT],
    ("Manifest", "format_version"): [manifest.FORMAT_VERSION],
    ("Sampling", "addressing"): ["repeat", "clamp"],
    ("Sampling", "wrap_s"): ["repeat", "clamp", "mirror"],
    ("Sampling", "wrap_t"): ["repeat", "clamp", "mirror"],
    ("Output", "kind"): ["color", "normal", "scalar"],
    ("Output", "encoding"): [material.SLOPE],
    ("Material", "status"): list(manifest.STATUSES),
    ("Job", "status"): [Status.BUILT, Status.FAILED, "not run"],
    ("BuildReport", "format"): [report.FORMAT],
    ("BuildReport", "format_version"): [report.FORMAT_VERSION],
    ("MaterialReport", "status"): list(manifest.STATUSES),
    ("MaterialReport", "cache"): [*report.CACHE_STATES, None],
    ("BC6H", "dxgi_format"): [95, 96],
    ("BC7", "dxgi_format"): [98],
}

_SCALARS = {str: "string", int: "integer", float: "number", bool: "boolean", type(None): "null"}


def _type(tp: Any, defs: dict[str, Any]) -> dict[str, Any]:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is Any:
        return {}
    if tp in _SCALARS:
        return {"type": _SCALARS[tp]}
    if origin in (typing.Union, types.UnionType):
        parts = [_type(a, defs) for a in args]
        if all(set(p) == {"type"} for p in parts):
            return {"type": [p["type"] for p in parts]}
        return {"anyOf": parts}
    if dataclasses.is_dataclass(tp):
        _define(tp, defs)
        return {"$ref": f"#/$defs/{tp.__name__}"}
    if origin in (tuple, list):
        if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
            return {"type": "array", "prefixItems": [_type(a, defs) for a in args],
                    "minItems": len(args), "maxItems": len(args)}
        return {"type": "array", "items": _type(args[0], defs) if args else {}}
    if origin is dict:
        return {"type": "object", "additionalProperties": _type(args[1], defs)}
    raise TypeError(f"no JSON Schema for {tp!r}")


def _object(cls, defs: dict[str, Any]) -> dict[str, Any]:
    hints = field_hints(cls)
    order = key_order(cls)
    props = {}
    for name in order:
        p = _type(hints[name], defs)
        if (cls.__name__, name) in ENUMS:
            p["enum"] = ENUMS[(cls.__name__, name)]
        props[name] = {"description": DESCRIPTIONS[(cls.__name__, name)], **p}
    optional = {f.name for f in dataclasses.fields(cls) if f.metadata.get("omit_none")}
    required = [n for n in order if n not in optional]
    return {"type": "object", "description": " ".join((cls.__doc__ or cls.__name__).split()),
            "properties": props, "required": required, "additionalProperties": False}


def _define(cls, defs: dict[str, Any]) -> None:
    if cls.__name__ not in defs:
        defs[cls.__name__] = None  # recursion guard
        defs[cls.__name__] = _object(cls, defs)


def json_schema(cls, file_name: str, title: str) -> dict[str, Any]:
    """A draft 2020-12 schema for the record ``cls`` (the file's top level)."""
    defs: dict[str, Any] = {}
    top = _object(cls, defs)
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "$id": BASE_URI + file_name,
            "title": title, **top, "$defs": dict(sorted(defs.items()))}


SCHEMAS = {
    "material.schema.json": (material.MaterialFile, "bcfpipe material.json"),
    "manifest.schema.json": (manifest.Manifest, "bcfpipe build manifest.json"),
    "report.schema.json": (report.BuildReport, "bcfpipe build --json report"),
}


def render(name: str) -> str:
    cls, title = SCHEMAS[name]
    return json.dumps(json_schema(cls, name, title), indent=2) + "\n"


def main(argv: list[str]) -> int:
    out = Path(argv[0]) if argv else SCHEMA_DIR
    for name in SCHEMAS:
        (out / name).write_text(render(name))
        print(out / name)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
