# Records every recipe into OUT (a ctest fixture for the scenes that load
# templates). 3D recipes are recorded at a coarse particle radius: the scene
# tests check that templates bind, not how they look.
file(GLOB recipes ${RECIPES}/*.json)
file(MAKE_DIRECTORY ${OUT})
foreach(recipe IN LISTS recipes)
  file(READ ${recipe} text)
  string(JSON dim GET "${text}" dimension)
  set(extra)
  if(dim EQUAL 3)
    set(extra --particle-radius 0.02)
  endif()
  execute_process(COMMAND ${FLOWCLIP} record ${recipe} --templates ${OUT} --force --quiet ${extra}
                  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "recording ${recipe} failed (${rc}):\n${out}\n${err}")
  endif()
endforeach()
