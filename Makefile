# The verbs users type. Each target creates .venv and installs the project when missing.
# Simulations resume and never replace a finished file; the targets that derive reports (and the demo,
# which is small) pass --overwrite, so that rerunning a target rebuilds its output (docs/outputs.md).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
GONIO  := $(VENV)/bin/gonio
STAMP  := $(VENV)/.installed
DEMO   := results/demo
DEMO_RAYS ?= 200000

.PHONY: setup test test-slow demo bench database report appendix-e validate-inverse tables ms-database lut clean

QUALITY ?= quick
DATABASE ?= configs/bati2019.toml
DB_OUT ?= results/bati2019
# Bati 2019 appendix E (configs/appendix-e.toml): demo ~1 min, quick ~3 min, full ~ 30 min on 2 cores
APPE_QUALITY ?= full
APPE_OUT ?= results/appendix-e-$(APPE_QUALITY)
# multiple-scattering twins of the 2019 database (configs/bati2019-ms.toml), compared with $(DB_OUT)
MS_OUT ?= results/bati2019-ms

$(STAMP): pyproject.toml examples/plugin-model/pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	$(PY) -m pip install --quiet -e examples/plugin-model
	touch $(STAMP)

setup: $(STAMP)

# two workers, whole files per worker (module fixtures built once), sharing one numba cache
# (tests/conftest.py): numba's compiles are single-threaded
test: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile

test-slow: $(STAMP)
	$(PY) -m pytest -q -m slow

demo: $(STAMP)
	mkdir -p $(DEMO)
	@for m in plastic metal slab; do \
	  $(GONIO) simulate configs/examples/$$m.toml --out $(DEMO)/$$m.h5 --rays $(DEMO_RAYS) --overwrite || exit $$?; \
	done
	@echo
	@for m in plastic metal slab; do $(GONIO) info $(DEMO)/$$m.h5 || exit $$?; echo; done
	$(GONIO) evaluate $(DEMO)/metal.h5
	@echo
	@# your own models (docs/models.md section 9): a plugin (examples/plugin-model, installed by the set-up) and
	@# a Mitsuba 3 BSDF from a file, beside a built-in model
	$(GONIO) evaluate $(DEMO)/plastic.h5 --model ww-bati19 --model coated-diffuse --model mitsuba:configs/mitsuba/plastic-p1.xml
	@echo
	$(GONIO) simulate configs/examples/metal.toml --out $(DEMO)/metal-rgl.h5 --parametrization rgl --rays $(DEMO_RAYS) --overwrite
	$(GONIO) export $(DEMO)/metal-rgl.h5 --format rgl --out $(DEMO)/metal_rgb.bsdf --overwrite
	$(GONIO) export $(DEMO)/metal-rgl.h5 --format rgl --out $(DEMO)/metal_spec.bsdf --spectral --overwrite
	@echo
	@# spectral light (docs/spectral.md): measured gold in 30 wavelength bins, and a thin film
	$(GONIO) simulate configs/examples/gold-spectral.toml --out $(DEMO)/gold-spectral.h5 --rays 20000 --overwrite
	$(GONIO) simulate configs/examples/soap-film.toml --out $(DEMO)/soap-film.h5 --rays 50000 --incident 0,20,40,60,80 --overwrite
	$(GONIO) render $(DEMO)/soap-film.h5 --out $(DEMO)/soap-film.png --light-angle 45 --size 256 --overwrite
	@echo
	$(GONIO) database simulate $(DATABASE) --out $(DEMO)/bati2019 --quality demo --only '*2-a0_0.2*'
	$(GONIO) report $(DEMO)/bati2019 --out $(DEMO)/bati2019-report --overwrite
	@echo
	@echo "demo files: $(DEMO)/plastic.h5 $(DEMO)/metal.h5 $(DEMO)/slab.h5, spectral $(DEMO)/gold-spectral.h5 $(DEMO)/soap-film.h5, and $(DEMO)/bati2019/"
	@echo "the metal for Mitsuba 3 and pbrt-v4 (docs/rgl-format.md): $(abspath $(DEMO))/metal_rgb.bsdf (Mitsuba RGB), $(abspath $(DEMO))/metal_spec.bsdf (pbrt-v4, Mitsuba spectral)"
	@echo "HTML report: $(abspath $(DEMO))/bati2019-report/index.html"

database: $(STAMP)
	$(GONIO) database simulate $(DATABASE) --out $(DB_OUT) --quality $(QUALITY)

report: $(STAMP)
	$(GONIO) report $(DB_OUT) --out $(DB_OUT)/report --overwrite

# resumable: rerunning after an interruption traces only what is missing; the report reuses its cache
appendix-e: $(STAMP)
	$(GONIO) database simulate configs/appendix-e.toml --out $(APPE_OUT) --quality $(APPE_QUALITY)
	$(GONIO) report $(APPE_OUT) --out $(APPE_OUT)-report --model belcour-fwd --incidents 30,80 --overwrite
	@echo "appendix E: $(abspath $(APPE_OUT))-report/appendix-e.md"

# resumable; simulates the single-scattering twin too if $(DB_OUT) lacks it (same QUALITY), then the
# MS report with the table multiple-scattering.md (docs/report.md)
ms-database: $(STAMP)
	$(GONIO) database simulate configs/bati2019-ms.toml --out $(MS_OUT) --quality $(QUALITY)
	$(GONIO) database simulate $(DATABASE) --out $(DB_OUT) --quality $(QUALITY)
	$(GONIO) report $(MS_OUT) --out $(MS_OUT)-report --compare-to $(DB_OUT) --overwrite
	@echo "multiple scattering: $(abspath $(MS_OUT))-report/multiple-scattering.md"

validate-inverse: $(STAMP)
	$(GONIO) validate-inverse configs/inverse/cases.toml --simulate --json results/inverse/validation.json --report results/inverse/report --overwrite

bench: $(STAMP)
	$(PY) benchmarks/bench.py
	$(PY) benchmarks/bench_harness.py
	$(PY) benchmarks/bench_inverse.py
	$(PY) benchmarks/bench_accuracy.py

tables: $(STAMP)
	$(GONIO) tables --masking all --check 200

# Issue 35 (docs/lut.md): a renderer's table with a standard error per cell. Default: Blender Cycles'
# 32 x 32 table_ggx_E at a target standard error of 1.5e-4 (~12 min on 2 cores); resumable (rerun after
# an interruption), never replaces a finished table (LUT_FLAGS=--overwrite does). LUT_PUBLISHED=path/to/
# shader.tables compares with Cycles' stored numbers; LUT=configs/lut/coat-darkening.toml for another table.
LUT ?= configs/lut/cycles-ggx-E.toml
LUT_OUT ?= results/lut
LUT_PUBLISHED ?=
LUT_FLAGS ?=
lut: $(STAMP)
	$(GONIO) lut $(LUT) --out $(LUT_OUT) $(if $(LUT_PUBLISHED),--published $(LUT_PUBLISHED),) $(LUT_FLAGS)

clean:
	rm -rf $(VENV) build *.egg-info
	find . -name __pycache__ -type d -prune -exec rm -rf {} +

# Issue 13 section 3 (configs/production.toml, docs/production.md): simulate the production coats
# (resumable; add --scheduler via PRODUCTION_FLAGS for Dask), measure the effective darkening and
# roughening, fit the replacement formulas and write $(PRODUCTION_OUT)/summary.json and production.md.
# full: ~25 min on 2 idle cores (docs/production.md section 6); demo: configs/production-demo.toml, 20 s with
# warm caches, 46 s on first use after an install or a code change (compiling; measured on the 2-core VM).
.PHONY: production
PRODUCTION_QUALITY ?= full
PRODUCTION_CONFIG ?= configs/production$(if $(filter demo,$(PRODUCTION_QUALITY)),-demo,).toml
PRODUCTION_DB ?= results/production-db-$(PRODUCTION_QUALITY)
PRODUCTION_OUT ?= results/production$(if $(filter full,$(PRODUCTION_QUALITY)),,-$(PRODUCTION_QUALITY))
PRODUCTION_FLAGS ?=

production: $(STAMP)
	$(GONIO) database simulate $(PRODUCTION_CONFIG) --out $(PRODUCTION_DB) --quality $(PRODUCTION_QUALITY) $(PRODUCTION_FLAGS)
	$(GONIO) production $(PRODUCTION_DB) --out $(PRODUCTION_OUT) --overwrite
	@echo "production coats: $(abspath $(PRODUCTION_OUT))/production.md"
