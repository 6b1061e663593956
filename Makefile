# The README's two commands: `make run` and `make test`. Both set up what a
# fresh Debian 12 machine is missing, then build in Release.
BUILD_DIR ?= build
BUILD_TYPE ?= Release
JOBS ?= $(shell nproc)
SCENE ?= scenes/dambreak2d.json
CMAKE_FLAGS ?=

.PHONY: all setup build templates run test bench clean

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

run: build templates
	$(BUILD_DIR)/flowclip run $(SCENE) --seconds 2 --stats $(BUILD_DIR)/last-run-stats.json

test: build templates
	cd $(BUILD_DIR) && ctest --output-on-failure -j 1
	$(BUILD_DIR)/venv/bin/python -m pytest -q tests

bench: build
	$(BUILD_DIR)/flowclip bench solver

clean:
	rm -rf $(BUILD_DIR)
