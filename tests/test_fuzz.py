"""Issue 11, item 5: bad input everywhere. Mutated real files (bit flips, overwritten bytes,
truncation, insertion, duplication, splicing) and generated texts go through every reader; each
must return or raise its documented one-line error (an InputError or the reader's ValueError),
never anything else, and never take more than 10 s.

The default suite runs a few hundred cases per reader; ``-m slow`` runs 10,000
(``BCFPIPE_FUZZ_N`` and ``BCFPIPE_FUZZ_SEED`` override). Each run prints its counts."""
from __future__ import annotations
from bcfpipe.builder import Execution

import json
import os
import random
import re
import shutil
import time
from pathlib import Path

import pytest

from cli_run import run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bcfpipe.config import TrainingOptions
from bcfpipe.errors import InputError

REPO = Path(__file__).resolve().parents[1]
LIMIT_S = 10.0


def mutate(data: bytes, rng: random.Random, donor: bytes = b"") -> bytes:
    """One to three random edits of ``data``."""
    b = bytearray(data)
    for _ in range(rng.randint(1, 3)):
        op = rng.randrange(6)
        if not b:
            b += bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
            continue
        i = rng.randrange(len(b))
        if op == 0:
            b[i] ^= 1 << rng.randrange(8)
        elif op == 1:
            b[i] = rng.choice((0, 0xFF, 0x7F, 0x80, rng.randrange(256)))
        elif op == 2:
            del b[rng.randrange(len(b) + 1):]
        elif op == 3:
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
        elif op == 4:
            j = rng.randrange(len(b))
            b[i:i] = b[j:j + rng.randint(1, 64)]
        else:
            cut = rng.randrange(len(donor) + 1) if donor else 0
            b = b[:i] + bytearray(donor[cut:cut + rng.randint(1, 256)])
    return bytes(b)


def mutate_json(text: str, rng: random.Random) -> str:
    """A structural edit of a JSON document: a value replaced by another type, or a key dropped."""
    doc = json.loads(text)
    nodes = []

    def walk(x):
        if isinstance(x, dict):
            for k in list(x):
                nodes.append((x, k))
                walk(x[k])
        elif isinstance(x, list):
            for k in range(len(x)):
                nodes.append((x, k))
                walk(x[k])
    walk(doc)
    for _ in range(rng.randint(1, 3)):
        parent, key = rng.choice(nodes)
        try:
            if isinstance(parent, dict) and rng.random() < 0.3:
                del parent[key]
            else:
                parent[key] = rng.choice([None, -1, 1e308, "x", [], {}, True, 2 ** 64, "../../etc/passwd"])
        except (KeyError, IndexError):
            pass
    return json.dumps(doc)


def count(default: int) -> int:
    return int(os.environ.get("BCFPIPE_FUZZ_N", default))


def run_cases(name: str, n: int, make, check, allowed: tuple[type[BaseException], ...]) -> dict:
    """Feed ``n`` inputs from ``make(rng)`` to ``check``; anything but ``allowed`` fails the test."""
    rng = random.Random(int(os.environ.get("BCFPIPE_FUZZ_SEED", 1234)))
    stats = {"cases": 0, "accepted": 0, "refused": 0, "slowest_s": 0.0}
    for _ in range(n):
        case = make(rng)
        t0 = time.perf_counter()
        try:
            check(case)
            stats["accepted"] += 1
        except allowed as e:
            assert "\n" not in str(e).strip() or name == "usd", f"{name}: a multi-line message: {e!s}"
            stats["refused"] += 1
        except BaseException as e:  # noqa: BLE001 - that is the finding
            raise AssertionError(f"{name}: {type(e).__name__}: {e} on input {case!r:.200}") from e
        dt = time.perf_counter() - t0
        stats["slowest_s"] = max(stats["slowest_s"], dt)
        assert dt < LIMIT_S, f"{name}: {dt:.1f}s on one input"
        stats["cases"] += 1
    print(f"fuzz {name}: {stats}")
    return stats


@pytest.fixture(scope="module")
def real_files(tmp_path_factory):
    """Files bcfpipe wrote: a DDS, weight records, material.json and manifest.json of a build."""
    from bcfpipe.builder import build
    from test_build import copy_samples

    root = tmp_path_factory.mktemp("fuzz")
    scene = copy_samples(root)
    r = build(scene, root / "out", execution=Execution(cache=False), training=TrainingOptions(profile="tiny", preset="smoke", seed=0, layout="neural"))
    mat = root / "out" / "materials" / r.plan.jobs[0].name
    return {"dds": (mat / "T0.dds").read_bytes(), "dds2": (mat / "T3.dds").read_bytes(),
            "record": (mat / "weights.bin").read_bytes(), "buffer": (root / "out" / "weights.bin").read_bytes(),
            "material": (mat / "material.json").read_text(), "manifest": (root / "out" / "manifest.json").read_text(),
            "usda": scene.read_text(), "root": root, "built": r.root_layer}


def _dds(real_files, n):
    from bcfpipe.formats import dds

    def check(data):
        tex = dds.parse(data, "fuzz.dds")
        assert tex.levels  # a file that parses has its blocks
    return run_cases("dds", n, lambda r: mutate(real_files["dds"], r, real_files["dds2"]), check, (dds.DdsError,))


def _weights(real_files, n):
    from bcfpipe.formats import weights
    from bcfpipe.model.decoder import from_bytes

    def check(data):
        for e in weights.unpack(data):
            from_bytes(data, e.offset)
    run_cases("weights.bin", n, lambda r: mutate(real_files["buffer"], r, real_files["record"]), check,
              (ValueError,))
    return run_cases("BCFW record", n, lambda r: mutate(real_files["record"], r), lambda d: from_bytes(d),
                     (ValueError,))


def _json_reader(real_files, n, which, tmp):
    from bcfpipe.formats import manifest, material

    mod = {"material": material, "manifest": manifest}[which]
    path = tmp / mod.FILE

    def make(r):
        return mutate_json(real_files[which], r) if r.random() < 0.5 else \
            mutate(real_files[which].encode(), r).decode("latin-1")

    def check(text):
        path.write_text(text, encoding="latin-1")
        mod.read(tmp)
    return run_cases(which + ".json", n, make, check, (InputError,))


def _usd(real_files, n, tmp):
    """A mutated scene through the scan and through the renderer's reading of the stage."""
    from bcfpipe.render.frames import load_scene
    from bcfpipe.scan.stage import scan_stage

    path = tmp / "fuzz.usda"
    (tmp / "textures").mkdir(exist_ok=True)

    def check(text):
        path.write_bytes(text)
        scan_stage(path)
        load_scene(path, 32, 32, kinds=("original",))
    return run_cases("usd", n, lambda r: mutate(real_files["usda"].encode(), r), check, (InputError,))


def test_fuzz_readers(real_files, tmp_path):
    n = count(300)
    _dds(real_files, n)
    _weights(real_files, n)
    _json_reader(real_files, n, "material", tmp_path)
    _json_reader(real_files, n, "manifest", tmp_path)
    _usd(real_files, count(60), tmp_path)


@pytest.mark.slow
def test_fuzz_readers_10000(real_files, tmp_path):
    n = count(10_000)
    for f in (_dds, _weights):
        assert f(real_files, n)["cases"] == n
    for which in ("material", "manifest"):
        assert _json_reader(real_files, n, which, tmp_path)["cases"] == n
    assert _usd(real_files, n, tmp_path)["cases"] == n


_DECLARATION = re.compile(r"^(\s*(?:custom\s+)?(?:uniform\s+)?)([A-Za-z]\w*(?:\[\])?)(\s+[\w:.]+\s*=)", re.M)


def retyped(text: str):
    """``text`` once per attribute declaration and way to get its type wrong: a type name USD does
    not know (the layer opens; the value reads as Sdf.UnregisteredValue), and array-ness flipped."""
    for m in _DECLARATION.finditer(text):
        t = m.group(2)
        array = t.endswith("[]")
        for new in ("bogus[]" if array else "bogus", t[:-2] if array else t + "[]"):
            yield f"{t} -> {new} {m.group(3).strip()}", text[:m.start(2)] + new + text[m.end(2):]


def test_retyped_attributes_in_the_scene(real_files, tmp_path):
    """Every attribute of the sample scene with a wrong type: the scan and the renderer's reading
    of the stage return or raise InputError. An unknown type found by the 10,000-case fuzz used to
    raise TypeError from the texel-density scan."""
    from bcfpipe.render.frames import load_scene
    from bcfpipe.scan.stage import scan_stage

    shutil.copytree(REPO / "samples" / "textures", tmp_path / "textures")
    path = tmp_path / "retyped.usda"
    cases = list(retyped(real_files["usda"]))
    assert len(cases) > 300
    for label, text in cases:
        path.write_text(text)
        for what, read in (("scan", lambda: scan_stage(path)),
                           ("render", lambda: load_scene(path, 32, 32, kinds=("original",)))):
            try:
                read()
            except InputError:
                pass
            except Exception as e:  # noqa: BLE001 - that is the finding
                raise AssertionError(f"{what}, {label}: {type(e).__name__}: {e}") from e


def test_retyped_attributes_in_the_built_layer(real_files, tmp_path):
    """The same for every attribute of a build's overrides.usda, read for a neural frame: a damaged
    bcf value is refused with one line (InputError), never another exception."""
    from bcfpipe.render.frames import load_scene

    built = Path(real_files["built"])
    root = tmp_path / "copy"
    shutil.copytree(real_files["root"], root)
    out = root / built.parent.relative_to(real_files["root"])
    layer = out / "overrides.usda"
    original = layer.read_text()
    refused = 0
    for label, text in retyped(original):
        layer.write_text(text)
        try:
            load_scene(out / built.name, 32, 32, kinds=("neural",))
        except InputError:
            refused += 1
        except Exception as e:  # noqa: BLE001 - that is the finding
            raise AssertionError(f"{label}: {type(e).__name__}: {e}") from e
    assert refused > 0  # damaged bcf values are refused, not drawn with defaults


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.text(max_size=80))
def test_texture_spec_parser_never_crashes(text):
    """Any text either parses into a spec or is refused with one line (InputError or ValueError)."""
    from bcfpipe.texset.texture_set import TextureSpec

    try:
        spec = TextureSpec.parse(text)
    except (InputError, ValueError) as e:
        assert str(e) and "\n" not in str(e)
        return
    assert spec.semantic and spec.path and spec.channels


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_are_refused_by_the_binary_readers(data):
    from bcfpipe.formats import dds, weights
    from bcfpipe.model.decoder import from_bytes

    for read, errors in ((lambda d: dds.parse(d, "x.dds"), (dds.DdsError,)), (weights.unpack, (ValueError,)),
                         (from_bytes, (ValueError,))):
        try:
            read(data)
        except errors:
            pass


def test_the_cli_reports_a_mutated_file_in_one_line(real_files, tmp_path):
    """End to end: `bcfpipe dds info` and `bcfpipe verify` on damaged files exit 2 with one line."""
    rng = random.Random(5)
    bad = tmp_path / "bad.dds"
    bad.write_bytes(mutate(real_files["dds"], rng)[:100])
    p = run_cli("dds", "info", bad)
    assert p.returncode == 2 and "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1
    mat = tmp_path / "mat"
    mat.mkdir()
    (mat / "material.json").write_text(mutate_json(real_files["material"], rng))
    p = run_cli("verify", mat)
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
