"""`bcfpipe build`: turn the textured UsdPreviewSurface materials of a USD scene into neural
materials, and write a USD stage that uses them.

A build runs in three steps, each usable on its own (a cache or a distributed executor slots in
between them):

1. `plan` (plan.py) scans the stage (``bcfpipe.scan``; texture-set grouping in ``bcfpipe.scan.texture_sets``) and turns every material decided ``model`` into a
   `MaterialPlan`; materials whose texture sets are identical (the same files and channels, the
   same addressing) share one frozen, JSON-serialisable `MaterialJob`, whose ``content_hash``
   (xxh3-128 over the source file *bytes* and the training configuration, never paths or times)
   names its result.
2. `execute` (executor.py) trains the jobs, each in its own worker process (``ProcessPoolExecutor``, spawn
   context), with ``config.DEFAULT_THREADS`` (1) torch threads each unless told otherwise; ``jobs``
   (``--jobs N``) bounds the build to N busy cores, every pool and thread of its jobs within their
   shares (`core_shares`). A job that raises, or whose worker dies, becomes ``failed`` with a one-line reason; the others go on.
3. `assemble` (assemble.py) writes the combined ``weights.bin`` (`bcfpipe.formats.weights`), the USD layers
   (`bcfpipe.builder.usd_layer`) and ``manifest.json``.

`build` (run.py) takes what the content-addressed cache (`bcfpipe.cache`) holds, runs the rest in a
staging folder inside OUT, and then installs only the files whose bytes changed (sync.py: each file
replaced atomically, manifest.json last; an interrupted install is marked and repaired by the next
build). An existing OUT is only updated when it holds a bcfpipe ``manifest.json`` (or with
``force``); an OUT that contains the scene or one of its textures is always refused (inputs are
never modified), and nothing is written outside OUT and the cache.

Output folder (OUT, default ``<scene>.bcf/`` next to the scene)::

    <scene>.bcf.usda     the stage to open: sublayers overrides.usda and the input (relative paths)
    overrides.usda       variant selections + BcfNeuralMaterialAPI on every modelled Material
    weights.bin          all decoders, fp16, one table (see bcfpipe.formats.weights)
    manifest.json        per-material status, sources with hashes, targets, metrics, sizes, times
    materials/<name>/    the trainer's export per trained texture set: T0..T3.dds, weights.bin
                         (that decoder alone), decoder.onnx, material.json

What is modelled, and how (the contract with renderers):

* Only textured UsdPreviewSurface inputs become decoder outputs; constant inputs keep their
  authored USD values (nothing in the input's shading network is changed).
* Each (file, channel) is one decoder output, however many inputs read it. A normal map read
  through ``.rgb`` gives two outputs (x, y, stored as ``2 v - 1``); the decoder appends
  z = sqrt(1 - x^2 - y^2) after y, and ``normal.z`` is a target.
* The model reproduces *stored* texel values (no colour decoding; see bcfpipe.texset). Per target
  the overrides author ``colorSpace`` (``sRGB``/``raw``), ``scale`` and ``bias`` so that
  ``target = decode(y[channel]) * scale + bias`` equals what the UsdUVTexture would have produced:
  scale/bias are the texture's own (for normals adjusted for the ``2 v - 1`` encoding, so the
  usual scale 2 / bias -1 becomes 1 / 0), and ``colorSpace`` is the texture's sourceColorSpace with
  ``auto`` resolved as Hydra does (sRGB for 8-bit files with 3 or 4 channels, else raw; alpha is
  never sRGB). Normal maps are always treated as raw data; an sRGB-tagged normal map gets a
  warning. ``normal.z`` is always the unit-length reconstruction (scale 1, bias 0).
* Opacity, displacement and emissive colour are modelled like any other input when textured.
  Opacity is learnt as the filtered (mip-averaged) *coverage*, never thresholded: the authored
  ``opacityThreshold`` (a constant that stays in USD, or a target if textured) is applied by the
  renderer to the decoded opacity, exactly as UsdPreviewSurface applies it to the texture fetch, so
  cut-outs keep their threshold and get smooth, stable coverage at distance. Displacement is
  decoded at the vertex/tessellation stage by renderers that displace.
* Addressing is per axis, as the textures' wrapS / wrapT say it: repeat, clamp or mirror (``black``
  sampled as clamp, with a warning; ``useMetadata`` as repeat). Sets of different addressing are
  never merged; inputs of one material that disagree take the mode most use per axis, with a
  warning naming them (docs/build.md, "Addressing and uv"). The textures' st primvar and
  UsdTransform2d are recorded; textures of one material must share them (else a warning).
* The profile ``auto`` is capped by the source resolution (``config.resolve_profile``).

Exit codes (`BuildResult.exit_code`, and the CLI): 0 every modelled material was built (skipped
ones are reported, not errors); 1 at least one material failed; 2 bad input or refused OUT (raised
as `BuildError`, before any training).

Determinism: the same inputs, options and seed give the same DDS, weights, ONNX and USD files on
the same machine (CPU training with the same number of worker threads). ``manifest.json`` and ``material.json``
hold no times; the build's timings are in its report (``--json``).
"""

from __future__ import annotations

from bcfpipe.builder.assemble import assemble, default_out, root_layer_name
from bcfpipe.builder.executor import JobResult, cpu_count, default_jobs, execute, run_job
from bcfpipe.formats.manifest import FILE as MANIFEST, FORMAT as BUILD_FORMAT, WEIGHTS
from bcfpipe.builder.plan import (MATERIALS_DIR, OVERRIDES, BuildError, BuildPlan,
                                MaterialJob, MaterialPlan, TargetMap, plan)
from bcfpipe.builder.options import Execution, ExecutorName, Selection
from bcfpipe.builder.run import BuildResult, build, check_out

__all__ = [
    "BuildError", "TargetMap", "MaterialJob", "MaterialPlan", "BuildPlan", "JobResult", "BuildResult",
    "Selection", "Execution", "ExecutorName", "plan", "execute", "assemble", "build", "check_out", "default_jobs", "default_out", "root_layer_name",
    "cpu_count", "run_job", "MANIFEST", "WEIGHTS", "OVERRIDES", "MATERIALS_DIR", "BUILD_FORMAT",
]
