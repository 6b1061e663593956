# Records every recipe into OUT (a ctest fixture for the scenes that load
# templates): each recipe must record. They are recorded at a coarse
# particle radius (2D 0.01 m, 3D 0.03 m), the one the scene smoke tests run
# at: those check that templates bind and the scenes run, not how they look.
file(GLOB recipes ${RECIPES}/*.json)
file(MAKE_DIRECTORY ${OUT})
foreach(recipe IN LISTS recipes)
  file(READ ${recipe} text)
  string(JSON dim GET "${text}" dimension)
  if(dim EQUAL 3)
    set(extra --particle-radius 0.03)
  else()
    set(extra --particle-radius 0.01)
  endif()
  execute_process(COMMAND ${FLOWCLIP} record ${recipe} --templates ${OUT} --force --quiet ${extra}
                  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "recording ${recipe} failed (${rc}):\n${out}\n${err}")
  endif()
endforeach()
