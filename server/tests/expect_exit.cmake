# Runs one command and checks its exit status and output (stdout + stderr).
#
#   cmake -DCMD="exe|arg1|arg2" -DEXPECT_CODE=2
#         [-DEXPECT_REGEX=regex] [-DEXPECT_TEXT=literal] [-DWORKDIR=dir]
#         -P expect_exit.cmake
#
# CMD separates arguments with "|" because a ";" list does not survive being
# passed through add_test(); a ";" list is accepted too when run by hand.
# EXPECT_TEXT is matched literally, so key paths such as
# fluid_blocks[0].max[0] need no regex escaping.
if(NOT DEFINED CMD OR CMD STREQUAL "")
  message(FATAL_ERROR "expect_exit.cmake: CMD is not set")
endif()
if(NOT DEFINED EXPECT_CODE)
  message(FATAL_ERROR "expect_exit.cmake: EXPECT_CODE is not set")
endif()
string(REPLACE "|" ";" cmd "${CMD}")
if(NOT DEFINED WORKDIR)
  set(WORKDIR ".")
endif()

execute_process(COMMAND ${cmd}
  WORKING_DIRECTORY "${WORKDIR}"
  RESULT_VARIABLE code
  OUTPUT_VARIABLE out
  ERROR_VARIABLE err
  TIMEOUT 300)
set(all "${out}${err}")
string(REPLACE ";" " " shown "${cmd}")

# A crash yields a text such as "Segmentation fault", never equal to a number.
if(NOT "${code}" STREQUAL "${EXPECT_CODE}")
  message(FATAL_ERROR "`${shown}` exited with '${code}', expected ${EXPECT_CODE}\n--- stdout:\n${out}\n--- stderr:\n${err}")
endif()
if(DEFINED EXPECT_REGEX AND NOT EXPECT_REGEX STREQUAL "")
  if(NOT all MATCHES "${EXPECT_REGEX}")
    message(FATAL_ERROR "output of `${shown}` does not match regex '${EXPECT_REGEX}'\n--- stdout:\n${out}\n--- stderr:\n${err}")
  endif()
endif()
if(DEFINED EXPECT_TEXT AND NOT EXPECT_TEXT STREQUAL "")
  string(FIND "${all}" "${EXPECT_TEXT}" pos)
  if(pos EQUAL -1)
    message(FATAL_ERROR "output of `${shown}` does not contain '${EXPECT_TEXT}'\n--- stdout:\n${out}\n--- stderr:\n${err}")
  endif()
endif()
message(STATUS "ok: `${shown}` exited ${code}")
