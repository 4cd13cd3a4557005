# Two entry points (see README): `make demo` and `make test`. Both set up first.
PY := .venv/bin/python
BCF := .venv/bin/bcfpipe
PYTEST_ARGS ?=

.PHONY: setup demo test test-install test-all decoders clean
setup:
	@bash scripts/setup.sh

# --layout neural shows the neural materials and their GLSL-against-ONNX check; the default layout
# (auto) keeps the sample scene's BC textures, which the features do not beat close up (README)
demo: setup
	$(BCF) build samples/sample_scene.usda --quality draft --layout neural --verify

# --dist loadscope: a module's tests on one worker, so its module-scoped builds run once, not once per
# worker (test_wrap's two builds: 53 s on each worker before); the tests of the long modules that
# share nothing go one by one to whichever worker is free, the longest modules first (tests/conftest.py)
test: setup
	$(PY) -m pytest -n 2 --dist loadscope --durations=15 $(PYTEST_ARGS)

# the package as a user installs it (tests/test_install.py, slow: about 4 min): the sdist and the wheel,
# the wheel in a new venv with only torch beside it, build --verify and render run outside the repository
test-install: setup
	$(PY) -m pytest -p no:xdist -m slow tests/test_install.py $(PYTEST_ARGS)

test-all: setup
	$(PY) -m pytest -n 2 --dist loadscope -m "" $(PYTEST_ARGS)

# the shipped HLSL / SPIR-V / Metal decoders (bcfpipe/decoders/) made anew from glsl/ after a change
# there; tests/test_shader_targets.py fails while they are stale
decoders: setup
	$(BCF) shaders -o bcfpipe/decoders

clean:
	rm -rf .venv build *.egg-info out
