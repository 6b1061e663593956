# Command-line tests of scene validation: `flowclip run <bad scene>` must exit
# with status 2 (bad input) and name the offending key path. Included by
# server/CMakeLists.txt; run with `ctest -L cli`.
set(FC_CLI_TESTS_DIR ${CMAKE_CURRENT_LIST_DIR})
set(FC_BAD_SCENES ${FC_CLI_TESTS_DIR}/bad_scenes)

# fc_cli_expect(<test name> <exit code> <literal text expected in output> <flowclip args...>)
function(fc_cli_expect name code text)
  list(JOIN ARGN "|" args)
  add_test(NAME ${name}
    COMMAND ${CMAKE_COMMAND} "-DCMD=$<TARGET_FILE:flowclip>|${args}" -DEXPECT_CODE=${code}
            "-DEXPECT_TEXT=${text}" -P ${FC_CLI_TESTS_DIR}/expect_exit.cmake)
  set_tests_properties(${name} PROPERTIES LABELS cli TIMEOUT 300)
endfunction()

# One bad scene per validation rule: file name (without .json) and the key
# path the error must name, as "<path>:" so that the path, not some other
# mention of the key, is checked.
set(FC_BAD_SCENE_CASES
  "unknown_key_top=gravty:"
  "unknown_key_nested=fluid_blocks[0].velocty:"
  "unknown_solver_param=solver.density_tolerance:"
  "wrong_type_string=particle_radius:"
  "wrong_type_integer_param=settings.reorder_interval:"
  "wrong_type_boolean_param=solver.divergence_solve:"
  "negative_radius=particle_radius:"
  "vector_wrong_length=gravity:"
  "huge_param=solver.density_tolerance_pct:"
  "out_of_range_param=settings.cfl_factor:"
  "domain_inverted=domain:"
  "block_inverted=fluid_blocks[0]:"
  "block_outside_domain=fluid_blocks[0].max[0]:"
  "block_in_obstacle=fluid_blocks[0]:"
  "block_near_obstacle=fluid_blocks[0]:"
  "obstacle_radius_zero=obstacles[0].radius:"
  "disk_in_3d=obstacles[0].type:"
  "mesh_in_2d=obstacles[0].type:"
  # Bad OBJ files of mesh obstacles (bad_scenes/meshes/): the file key path.
  "mesh_malformed=obstacles[1].file:"
  "mesh_index_out_of_range=obstacles[1].file:"
  "mesh_open_box=obstacles[1].file:"
  "mesh_nonfinite=obstacles[1].file:"
  "mesh_missing=obstacles[1].file:"
  "unknown_phase=fluid_blocks[0].phase:"
  "duplicate_phase=phases[1].name:"
  "rest_density_zero=phases[0].rest_density:"
  "negative_viscosity=phases[0].viscosity:"
  "unknown_solver=solver.method:"
  "unknown_effect=effects[0]:"
  "duplicate_effect=effects[1]:"
  "too_many_particles=fluid_blocks:"
  "max_particles_out_of_range=max_particles:"
  "no_fluid_blocks=fluid_blocks:"
  "bad_dimension=dimension:"
  "duplicate_key=particle_radius:"
  # File-level errors name the file with line and column instead of a key.
  "malformed=malformed.json:3:18: malformed JSON"
  "number_overflow=number_overflow.json:4:22: malformed JSON"
)
foreach(case IN LISTS FC_BAD_SCENE_CASES)
  string(FIND "${case}" "=" eq)
  string(SUBSTRING "${case}" 0 ${eq} file)
  math(EXPR eq "${eq} + 1")
  string(SUBSTRING "${case}" ${eq} -1 text)
  fc_cli_expect(cli_bad_scene_${file} 2 "${text}" run ${FC_BAD_SCENES}/${file}.json --frames 1)
endforeach()

# The open box's message says what is wrong with the mesh and where.
fc_cli_expect(cli_bad_scene_mesh_not_closed 2 "the mesh is not closed: 4 edges belong to one face only, e.g. the edge from vertex"
  run ${FC_BAD_SCENES}/mesh_open_box.json --frames 1)
fc_cli_expect(cli_bad_scene_missing_file 2 "does_not_exist.json" run ${FC_BAD_SCENES}/does_not_exist.json --frames 1)
fc_cli_expect(cli_bad_particle_radius_override 2 "fluid_blocks:"
  run ${FC_BAD_SCENES}/../../../scenes/bench/dambreak2d_r010.json --particle-radius 0.0001 --frames 1)

# Every shipped scene loads, binds its template instances and runs 15
# frames (past every shipped instance's start) without a non-finite value
# (run exits non-zero on one), at a coarse particle radius (2D 0.01 m, 3D
# 0.03 m). The templates come from a fixture that records every recipe into
# the build tree at the same radii.
set(FC_TEST_TEMPLATES ${CMAKE_BINARY_DIR}/test-templates)
add_test(NAME cli_record_test_templates
  COMMAND ${CMAKE_COMMAND} -DFLOWCLIP=$<TARGET_FILE:flowclip> -DRECIPES=${FC_CLI_TESTS_DIR}/../../templates/recipes
          -DOUT=${FC_TEST_TEMPLATES} -P ${FC_CLI_TESTS_DIR}/record_test_templates.cmake)
set_tests_properties(cli_record_test_templates PROPERTIES LABELS cli TIMEOUT 600 FIXTURES_SETUP test_templates)
file(GLOB FC_SHIPPED_SCENES CONFIGURE_DEPENDS ${FC_CLI_TESTS_DIR}/../../scenes/*.json ${FC_CLI_TESTS_DIR}/../../scenes/bench/*.json)
foreach(scene IN LISTS FC_SHIPPED_SCENES)
  get_filename_component(stem ${scene} NAME_WE)
  get_filename_component(dir ${scene} DIRECTORY)
  get_filename_component(dir ${dir} NAME)
  file(READ ${scene} scene_text)
  string(JSON scene_dim GET "${scene_text}" dimension)
  if(scene_dim EQUAL 3)
    set(smoke_radius 0.03)
  else()
    set(smoke_radius 0.01)
  endif()
  fc_cli_expect(cli_scene_runs_${dir}_${stem} 0 "" run ${scene} --frames 15 --particle-radius ${smoke_radius} --quiet
                --templates ${FC_TEST_TEMPLATES})
  set_tests_properties(cli_scene_runs_${dir}_${stem} PROPERTIES FIXTURES_REQUIRED test_templates)
endforeach()
# A scene naming a template the database lacks: status 2, the path named.
fc_cli_expect(cli_scene_missing_template 2 "instances[0].template: no template 'drop2d'"
  run ${FC_CLI_TESTS_DIR}/../../scenes/drop2d.json --frames 1 --templates ${FC_BAD_SCENES})

# Templates: bad recipes and names exit with status 2 and say what is wrong;
# nothing is written (the output directory is the bad recipes' own folder,
# which holds no template).
set(FC_BAD_RECIPES ${FC_CLI_TESTS_DIR}/bad_recipes)
fc_cli_expect(cli_record_bad_region 2 "capture.region.min[1]:" record ${FC_BAD_RECIPES}/bad_region.json --templates ${FC_BAD_RECIPES})
fc_cli_expect(cli_record_bad_name 2 "capture.name: invalid template name '../evil'" record ${FC_BAD_RECIPES}/bad_name.json --templates ${FC_BAD_RECIPES})
fc_cli_expect(cli_templates_inspect_path 2 "invalid template name '../x'" templates inspect ../x --templates ${FC_BAD_RECIPES})
fc_cli_expect(cli_templates_inspect_missing 2 "no template 'nosuch'" templates inspect nosuch --templates ${FC_BAD_RECIPES})

# bench control: both ways of applying the forces on drop2d, two frames past
# the instance's start (t = 0.2 s); the table and a verdict are printed, the
# report written (its contents: tests/test_bench_reports.py).
fc_cli_expect(cli_bench_control 0 "drop2d: control is"
  bench control ${FC_CLI_TESTS_DIR}/../../scenes/drop2d.json --frames 14 --threads 1 --templates ${FC_TEST_TEMPLATES}
  --out ${CMAKE_BINARY_DIR}/cli-bench-control)
set_tests_properties(cli_bench_control PROPERTIES FIXTURES_REQUIRED test_templates)
# bench scenes: the paper's Table 1 columns beside its own row, in the report.
fc_cli_expect(cli_bench_scenes 0 "bench scenes: wrote ${CMAKE_BINARY_DIR}/cli-bench-scenes/scenes.md and scenes.json"
  bench scenes ${FC_CLI_TESTS_DIR}/../../scenes/drop2d.json --frames 14 --threads 1 --templates ${FC_TEST_TEMPLATES}
  --out ${CMAKE_BINARY_DIR}/cli-bench-scenes)
set_tests_properties(cli_bench_scenes PROPERTIES FIXTURES_REQUIRED test_templates)
# bench accuracy refuses a --double-binary that is not a double build and a
# template database without drop2d, before it runs any point.
fc_cli_expect(cli_bench_accuracy_not_double 2 "--double-binary: '$<TARGET_FILE:flowclip>' runs Real = float, not double"
  bench accuracy --quick --no-plots --out ${CMAKE_BINARY_DIR}/cli-accuracy --double-binary $<TARGET_FILE:flowclip>)
fc_cli_expect(cli_bench_accuracy_no_templates 2 "--templates: '${FC_BAD_RECIPES}' has no drop2d.h5"
  bench accuracy --quick --no-plots --out ${CMAKE_BINARY_DIR}/cli-accuracy --templates ${FC_BAD_RECIPES})
# run --control-setting is checked as the scene file's "control" object.
fc_cli_expect(cli_run_bad_control_setting 2 "control.forces_every_substep: '2' given by --control-setting"
  run ${FC_CLI_TESTS_DIR}/../../scenes/drop2d.json --frames 1 --control-setting forces_every_substep=2)

# run --boundary-setting sets a parameter of the model the run uses, checked as the scene file's "boundary".
fc_cli_expect(cli_run_boundary_setting 0 "boundary adami2012 (hydrostatic=1 constraint=1 ramp=0.25)"
  run ${FC_CLI_TESTS_DIR}/../../scenes/hydrostatic2d.json --frames 1 --boundary-setting constraint=1
  --boundary-setting ramp=0.25)
fc_cli_expect(cli_run_bad_boundary_setting 2 "boundary.ramp: '2' given by --boundary-setting"
  run ${FC_CLI_TESTS_DIR}/../../scenes/hydrostatic2d.json --frames 1 --boundary-setting ramp=2)
fc_cli_expect(cli_run_unknown_boundary_setting 2 "expected KEY=VALUE with KEY one of: hydrostatic, constraint, ramp"
  run ${FC_CLI_TESTS_DIR}/../../scenes/hydrostatic2d.json --frames 1 --boundary-setting map_spacing=1)

# run --solver-setting sets a parameter of the solver the run uses, checked as the scene file's "solver".
fc_cli_expect(cli_run_solver_setting 0 "divergence_solve=1 warm_start=0)"
  run ${FC_CLI_TESTS_DIR}/../../scenes/bench/dambreak2d_r010.json --frames 1 --particle-radius 0.02
  --solver-setting warm_start=0)
fc_cli_expect(cli_run_bad_solver_setting 2 "solver.density_tolerance_pct: '50' given by --solver-setting"
  run ${FC_CLI_TESTS_DIR}/../../scenes/bench/dambreak2d_r010.json --frames 1 --solver-setting density_tolerance_pct=50)
fc_cli_expect(cli_run_unknown_solver_setting 2 "expected KEY=VALUE with KEY one of: density_tolerance_pct"
  run ${FC_CLI_TESTS_DIR}/../../scenes/bench/dambreak2d_r010.json --frames 1 --solver-setting ramp=1)
# bench solver --solvers NAME:KEY=VALUE runs the solver with that parameter and labels its row so.
fc_cli_expect(cli_bench_solver_solver_setting 0 "dambreak2d_r010 with dfsph:density_tolerance_pct=0.02: 5476 particles"
  bench solver --scenes ${FC_CLI_TESTS_DIR}/../../scenes/bench/dambreak2d_r010.json --solvers dfsph:density_tolerance_pct=0.02
  --seconds 0.02 --threads 1 --out ${CMAKE_BINARY_DIR}/cli-bench-solver-setting)
# bench solver --boundaries NAME:KEY=VALUE runs the model with that parameter and labels its row so.
fc_cli_expect(cli_bench_solver_boundary_setting 0 "dambreak2d_r010 with dfsph (adami2012:constraint=1): 5476 particles"
  bench solver --scenes ${FC_CLI_TESTS_DIR}/../../scenes/bench/dambreak2d_r010.json --solvers dfsph
  --boundaries adami2012:constraint=1 --seconds 0.02 --threads 1 --out ${CMAKE_BINARY_DIR}/cli-bench-solver)

# --solver naming the scene's own solver keeps the scene's tolerances (the
# reference benchmarks run at theirs); another solver runs at its defaults.
fc_cli_expect(cli_solver_override_keeps_scene_tolerance 0 "solver dfsph (density_tolerance_pct=0.1 divergence_tolerance_pct=0.1"
  run ${FC_CLI_TESTS_DIR}/../../scenes/bench/dambreak2d_r010.json --frames 1 --particle-radius 0.02 --solver dfsph)
fc_cli_expect(cli_solver_override_other_solver_defaults 0 "solver wcsph (stiffness=50000 exponent=7"
  run ${FC_CLI_TESTS_DIR}/../../scenes/bench/dambreak2d_r010.json --frames 1 --particle-radius 0.02 --solver wcsph)
