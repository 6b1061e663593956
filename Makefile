# The README's two commands: `make run` and `make test`. Both set up what a
# fresh Debian 12 machine is missing, then build in Release (and the editor).
BUILD_DIR ?= build
BUILD_TYPE ?= Release
JOBS ?= $(shell nproc)
SCENE ?= scenes/dambreak2d.json
CMAKE_FLAGS ?=
PORT ?= 8080
ABS_BUILD_DIR = $(abspath $(BUILD_DIR))

.PHONY: all setup build web templates run run-headless docs gallery portable bench-portable test test-parts test-ctest test-pytest test-web test-web-only bench bench-accuracy bench-web clean \
  fuzz fuzz-build fuzz-regress test-fuzz asan-build test-asan bench-soak bench-cache bench-suite bench-spheric2 bench-batch \
  templates-paper bench-scenes-paper bench-scaling bench-template-streaming

# 2D templates are recorded when missing (seconds); larger ones on demand:
# build/flowclip record templates/recipes/letters3d.json
TEMPLATES_2D = drop2d column2d jet2d

all: build

setup:
	@tools/setup.sh

$(BUILD_DIR)/build.ninja:
	@cmake -S server -B $(BUILD_DIR) -G Ninja -DCMAKE_BUILD_TYPE=$(BUILD_TYPE) $(CMAKE_FLAGS) >/dev/null

build: setup $(BUILD_DIR)/build.ninja
	@cmake --build $(BUILD_DIR) -j $(JOBS)

templates/%.h5: templates/recipes/%.json | build
	$(BUILD_DIR)/flowclip record $< --templates templates --force --quiet

templates: $(foreach t,$(TEMPLATES_2D),templates/$(t).h5)

# The paper's scale (docs/benchmarks/paper-scale.md): every recipe the
# scenes of the paper's Table 1 play, recorded at its "paper" resolution into
# templates/paper/, and the boat's own hand (scale "paper-boat") into
# templates/paper-boat/. A template already there is kept, so a stopped run
# resumes at the first recipe still missing.
RECIPES_PAPER = drop2d wave2d blade2d waterjet2d jet2d doubledam2d honey3d blade3d hand3d letters3d
templates-paper: build
	@for r in $(RECIPES_PAPER); do $(BUILD_DIR)/flowclip record templates/recipes/$$r.json --scale paper --skip-existing || exit 1; done
	@$(BUILD_DIR)/flowclip record templates/recipes/hand3d.json --scale paper-boat --skip-existing

# The 3D dam break from 59k to a million particles: µs per particle-step and
# bytes per particle (bench/scaling/scaling.md; tools/bench_scaling.py).
bench-scaling: build
	$(BUILD_DIR)/venv/bin/python tools/bench_scaling.py

# Templates streamed under smaller --template-memory budgets against read
# whole (bench/template-streaming/streaming.md; tools/bench_template_streaming.py).
bench-template-streaming: templates-paper
	$(BUILD_DIR)/venv/bin/python tools/bench_template_streaming.py

# Table 1 at the paper's scale: bench/scenes-paper/scenes.md (+ .json).
BENCH_SCENES_PAPER_ARGS ?= --frames 60
bench-scenes-paper: templates-paper
	$(BUILD_DIR)/flowclip bench scenes --scale paper $(BENCH_SCENES_PAPER_ARGS)

# The editor (web/ -> web/dist). It imports the TypeScript wire code the C++
# build generates ($(BUILD_DIR)/generated/ts), hence after `build`.
web: build
	@cd web && FLOWCLIP_BUILD_DIR=$(ABS_BUILD_DIR) node scripts/build.mjs

# The server with the editor: open the printed URL.
run: build templates web
	@echo "FlowClip editor: http://127.0.0.1:$(PORT)/  (Ctrl-C stops the server)"
	$(BUILD_DIR)/flowclip serve --port $(PORT) --web web/dist

run-headless: build templates
	$(BUILD_DIR)/flowclip run $(SCENE) --seconds 2 --stats $(BUILD_DIR)/last-run-stats.json

# The parts of `make test`, in order (tools/time_suite.py times each).
# ctest runs one test at a time: each uses both cores (OpenMP), and two at
# once would make every barrier wait for a descheduled thread.
TEST_PARTS = test-ctest test-pytest docs test-web-only test-fuzz test-asan

test: build templates web
	@for part in $(TEST_PARTS); do $(MAKE) --no-print-directory $$part || exit 1; done

# OpenMP threads that wait at a barrier spin briefly, then sleep: the
# runtimes' long default spin (libgomp's for the Release build, LLVM's
# libomp for the sanitized ones) keeps a waiting thread on a core that a
# busy machine's other processes need, and the suite's small scenes then
# run up to 6x slower.
$(TEST_PARTS) test-web: export GOMP_SPINCOUNT ?= 1000
$(TEST_PARTS) test-web: export KMP_BLOCKTIME ?= 1

test-parts:
	@echo $(TEST_PARTS)

test-ctest:
	cd $(BUILD_DIR) && ctest --output-on-failure -j 1

test-pytest:
	$(BUILD_DIR)/venv/bin/python -m pytest -q tests

# The editor's Playwright tests (headless Debian Chromium against a real
# server); the last line is "N passed, N failed" from the JSON report.
test-web: build templates web
	@$(MAKE) --no-print-directory test-web-only

test-web-only:
	@cd web && FLOWCLIP_BUILD_DIR=$(ABS_BUILD_DIR) ./node_modules/.bin/playwright test; \
	  status=$$?; node scripts/report-summary.mjs playwright-report/results.json; exit $$status

bench: build
	$(BUILD_DIR)/flowclip bench solver

# Executables for other x86-64 CPUs (docs/portable.md): one per x86-64 level
# and the launcher that picks one, in $(PORTABLE_DIR)/bin; the Docker image
# ships them. bench-portable measures them beside the native build.
PORTABLE_DIR ?= build-portable
portable: setup
	@tools/build_portable.sh $(PORTABLE_DIR) $(JOBS)

bench-portable: build portable
	@for level in x86-64-v3 x86-64-v4; do \
	  $(BUILD_DIR)/venv/bin/python tools/compare_builds.py --old $(BUILD_DIR)/flowclip \
	    --new $(PORTABLE_DIR)/bin/flowclip-$$level scenes/dambreak2d.json:60 scenes/dambreak3d.json:20 \
	    --repeat 5 --out bench/portable/$$level || exit 1; \
	done

# The accuracy/cost study's full sweep (docs/benchmarks/accuracy.md; 1 thread
# per run, the fastest of 3: about 15 min at load 5) into bench/accuracy,
# with a Real = double build beside the float one for the precision points
# and the templates of every 2D template scene for their fidelity.
# `make test` runs its --quick smoke run.
TEMPLATES_ACCURACY = $(TEMPLATES_2D) wave2d waterjet2d doubledam2d blade2d
bench-accuracy: build $(foreach t,$(TEMPLATES_ACCURACY),templates/$(t).h5)
	@cmake -S server -B $(BUILD_DIR)-double -G Ninja -DCMAKE_BUILD_TYPE=$(BUILD_TYPE) -DFLOWCLIP_DOUBLE=ON $(CMAKE_FLAGS) >/dev/null
	@cmake --build $(BUILD_DIR)-double --target flowclip -j $(JOBS)
	$(BUILD_DIR)/flowclip bench accuracy --out bench/accuracy --double-binary $(BUILD_DIR)-double/flowclip --threads 1 --repeat 3

# The editor's browser benchmark (headless Chromium, software GL): decode +
# upload + draw per frame at 100k and 300k particles, bytes per frame.
# `make bench-web BENCH_WEB_ARGS=--quick` for a short run.
BENCH_WEB_ARGS ?=
bench-web: build templates web
	@cd web && FLOWCLIP_BUILD_DIR=$(ABS_BUILD_DIR) node scripts/bench-browser.mjs $(BENCH_WEB_ARGS)

# Fuzzing and sanitizers (docs/fuzzing.md). The libFuzzer targets of
# server/fuzz/ are built with clang, ASan and UBSan in $(FUZZ_BUILD_DIR);
# `make fuzz` runs each for FUZZ_SECONDS (new inputs go to
# $(FUZZ_BUILD_DIR)/fuzz-corpus, crashes to $(FUZZ_BUILD_DIR)/fuzz-artifacts).
# `make test-fuzz` replays every corpus (the regress-* inputs of known bugs
# included) and fuzzes each target for FUZZ_TEST_SECONDS; `make test-asan`
# runs the pytest suite once against flowclip built with ASan + UBSan
# ($(ASAN_BUILD_DIR), clang). `make test` runs both after the main suite.
FUZZ_BUILD_DIR ?= build-fuzz
ASAN_BUILD_DIR ?= build-asan
FUZZ_SECONDS ?= 600
FUZZ_TEST_SECONDS ?= 30
FUZZ_JOBS ?= 2

$(FUZZ_BUILD_DIR)/build.ninja:
	@CC=clang CXX=clang++ cmake -S server -B $(FUZZ_BUILD_DIR) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DFLOWCLIP_FUZZ=ON $(CMAKE_FLAGS) >/dev/null

fuzz-build: setup $(FUZZ_BUILD_DIR)/build.ninja
	@cmake --build $(FUZZ_BUILD_DIR) --target fuzzers -j $(JOBS)

fuzz: fuzz-build
	@FUZZ_JOBS=$(FUZZ_JOBS) server/fuzz/run.sh fuzz $(FUZZ_BUILD_DIR) $(FUZZ_SECONDS)

fuzz-regress: fuzz-build
	@server/fuzz/run.sh regress $(FUZZ_BUILD_DIR)

# Fuzzing starts from the repository's corpus in a fresh folder each time, so
# that its start-up does not grow with every earlier run's inputs.
test-fuzz: fuzz-build
	@server/fuzz/run.sh regress $(FUZZ_BUILD_DIR)
	@scratch=$$(mktemp -d); FUZZ_SCRATCH=$$scratch FUZZ_JOBS=$(FUZZ_JOBS) server/fuzz/run.sh fuzz $(FUZZ_BUILD_DIR) $(FUZZ_TEST_SECONDS); \
	  status=$$?; rm -rf $$scratch; exit $$status

$(ASAN_BUILD_DIR)/build.ninja:
	@CC=clang CXX=clang++ cmake -S server -B $(ASAN_BUILD_DIR) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DFLOWCLIP_SANITIZE=ON $(CMAKE_FLAGS) >/dev/null

asan-build: setup $(ASAN_BUILD_DIR)/build.ninja
	@cmake --build $(ASAN_BUILD_DIR) --target flowclip -j $(JOBS)

# The pytest suite against the sanitized flowclip; any sanitizer report of
# any flowclip process fails it (server/fuzz/pytest_sanitized.sh).
test-asan: asan-build templates
	server/fuzz/pytest_sanitized.sh $(ASAN_BUILD_DIR) $(BUILD_DIR)/venv/bin/python

# The soak benchmark (docs/robustness.md): 8 sessions x 8 clients for 10
# minutes, report in bench/soak/.
bench-soak: build templates
	$(BUILD_DIR)/venv/bin/python tools/soak.py --out bench/soak

# The edit-and-see benchmark (docs/cache.md): edits at the start, middle and
# end of a simulated second on drop2d and a 3D tank, with checkpoints every
# 10 frames and without; report in bench/cache/ (about 5 min on 2 cores).
# `make bench-cache BENCH_CACHE_ARGS=--quick` for a short smoke run.
BENCH_CACHE_ARGS ?=
# The test suite's wall time, part by part: three runs in a row, the third
# with both cores kept busy by other processes; report in bench/suite/.
bench-suite: build templates web
	$(BUILD_DIR)/venv/bin/python tools/time_suite.py --out bench/suite $(BENCH_SUITE_ARGS)

bench-cache: build templates
	$(BUILD_DIR)/venv/bin/python tools/bench_cache.py --out bench/cache $(BENCH_CACHE_ARGS)

# Batch runs on a Dask cluster (docs/batch.md): the quick accuracy sweep one
# point after the other against --local 2, and a 3D export's frames meshed by
# `flowclip export --threads 1|2` against `flowclip-batch export --local 2`;
# report in bench/batch/ (a few minutes on 2 cores).
bench-batch: build templates
	$(BUILD_DIR)/venv/bin/python tools/bench_batch.py --out bench/batch $(BENCH_BATCH_ARGS)

# SPHERIC Test 2 (docs/benchmarks/accuracy.md): the 3D dam break against a
# box at the scene's resolution, the water height at the experiment's four
# gauges against the measured; report in bench/spheric2/ (minutes on 2 cores).
bench-spheric2: build
	$(BUILD_DIR)/venv/bin/python tools/spheric2.py --out bench/spheric2 $(BENCH_SPHERIC2_ARGS)

# Pictures of every shipped scene's surface (docs/images/gallery/, shown by
# the README and docs/surfaces.md): each scene run, meshed and rendered by
# Blender (Cycles on the CPU) from the camera stored in the scene; records the
# 3D templates first when missing. Not part of `make test` (an hour or more on
# 2 cores); tests/test_surface_export.py imports a small scene into Blender.
gallery: build templates
	$(BUILD_DIR)/venv/bin/python tools/gallery.py $(GALLERY_ARGS)

# The documentation site (docs/, mkdocs.yml) into site/, failing on a page
# missing from the navigation, a broken relative link or anchor. A few
# seconds; `make test` runs it as a check. The parameter reference is
# generated from the built binary's declarations (`flowclip params`).
docs: build
	@FLOWCLIP_BIN=$(ABS_BUILD_DIR)/flowclip NO_MKDOCS_2_WARNING=1 $(BUILD_DIR)/venv/bin/mkdocs build --strict --quiet
	@echo "docs: site/index.html"

clean:
	rm -rf $(BUILD_DIR) $(FUZZ_BUILD_DIR) $(ASAN_BUILD_DIR) clients/python/build clients/python/flowclip.egg-info
