# Set-up and entry points. `make demo` and `make test` work on a fresh Debian
# machine with no display: they install the Debian libraries Open3D needs
# (as root, when missing), create .venv and install the package into it.

PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Blender as a Python module (bpy, Python 3.11 only) in a venv of its own: the tests
# import the USD and OBJ outputs into real Blender with it. bpy 4.2 needs NumPy 1.
BLENDER_VENV := .venv-blender
BLENDER_STAMP := $(BLENDER_VENV)/.installed
BPY := bpy==4.2.*
# Shared libraries open3d loads (OpenGL, EGL, OpenMP, USB); Xvfb and xauth for the
# viewer window on a machine with no display, xdotool for the mouse and keys its tests use.
DEBIAN_PACKAGES := libgl1 libegl1 libgomp1 libusb-1.0-0 xvfb xauth xdotool

.PHONY: demo test bench system-deps install clean

demo: install
	$(BIN)/fracref run configs/example.yaml --out runs/example --force
	$(BIN)/fracref render runs/example --what slices --what iterations --out runs/example/renders --quiet
	@echo "results: runs/example (manifest.json), figures and videos: runs/example/renders (open the viewer: xvfb-run -a $(BIN)/fracref view runs/example, or without xvfb-run on a desktop)"

# Test files run on every core (one worker per file: a file's fixtures are made once, and the
# viewer's windows under Xvfb open one at a time).
test: install
	$(BIN)/python -m pytest -n auto --dist loadfile --no-loadscope-reorder

bench: install
	$(BIN)/python benchmarks/bench_fields.py
	$(BIN)/python benchmarks/bench_coarse.py
	$(BIN)/python benchmarks/bench_refine.py --repeat 3 --rounds 2
	$(BIN)/python benchmarks/bench_refine.py --repeat 3 --rounds 2 --cores 1
	$(BIN)/python benchmarks/bench_animate.py --triangles 200000
	$(BIN)/python benchmarks/fidelity.py

# The two environments are made side by side (each mostly one core: unpacking wheels, then the kernels'
# compilation in .venv), their output a line at a time; INSTALL_JOBS=1 makes them one after the other.
INSTALL_JOBS ?= 2
install: system-deps
	@$(MAKE) --no-print-directory --silent -j$(INSTALL_JOBS) --output-sync=line $(STAMP) $(BLENDER_STAMP)

system-deps:
	@if command -v dpkg >/dev/null 2>&1; then \
	  missing=""; \
	  for p in $(DEBIAN_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	  $(PYTHON) -c 'import ensurepip, venv' >/dev/null 2>&1 || missing="$$missing python3-venv"; \
	  if [ -n "$$missing" ]; then \
	    echo "installing Debian packages:$$missing"; \
	    if [ "$$(id -u)" -eq 0 ]; then SUDO=""; else SUDO="sudo"; fi; \
	    $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $$missing; \
	  fi; \
	fi

$(STAMP): pyproject.toml
	@echo "making $(VENV): the project and its packages, then the kernels' one-off compilation (a few minutes)"
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "Python >= 3.11 is required, found " + sys.version' 
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	$(BIN)/fracref compile  # the kernels' one-off compilation now, not at the first run
	@touch $(STAMP)

$(BLENDER_STAMP):
	@echo "making $(BLENDER_VENV): Blender as a Python module, for the tests' imports into Blender"
	$(PYTHON) -m venv $(BLENDER_VENV)
	$(BLENDER_VENV)/bin/python -m pip install --quiet '$(BPY)' 'numpy<2'
	@touch $(BLENDER_STAMP)

clean:
	rm -rf $(VENV) $(BLENDER_VENV) runs .pytest_cache
