# Run by ctest: install fluxcal into WORK_DIR/prefix, build the example against it, run the example.
# Then build tests/cpp/abi_consumer against the same install with -march=native and with
# -fsanitize=address (those the compiler accepts) and run them: a consumer whose flags change Eigen's
# defaults must still free what the library allocated (the exported target pins Eigen's memory ABI).
file(REMOVE_RECURSE ${WORK_DIR})
function(run)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  message(STATUS "${out}")
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "command failed (${rc}): ${ARGN}\n${out}\n${err}")
  endif()
endfunction()
run(${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${WORK_DIR}/prefix)
run(${CMAKE_COMMAND} -S ${EXAMPLE_DIR} -B ${WORK_DIR}/build -G ${GENERATOR}
    -DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix -DCMAKE_BUILD_TYPE=Release)
run(${CMAKE_COMMAND} --build ${WORK_DIR}/build)
run(${WORK_DIR}/build/calibrate_example)

run(${CMAKE_COMMAND} -S ${ABI_CONSUMER_DIR} -B ${WORK_DIR}/abi -G ${GENERATOR}
    -DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix -DCMAKE_BUILD_TYPE=Release)
run(${CMAKE_COMMAND} --build ${WORK_DIR}/abi)
file(READ ${WORK_DIR}/abi/variants.txt variants)
message(STATUS "ABI consumers built: ${variants}")
set(ENV{ASAN_OPTIONS} "detect_leaks=0:abort_on_error=0")  # the point is the heap, not leaks at exit
foreach(v IN LISTS variants)
  run(${WORK_DIR}/abi/${v})
endforeach()

# The example's usage error: a NORM that is not a number is named, not an uncaught std::stod exception.
file(WRITE ${WORK_DIR}/rows.txt "1 2 3\n4 5 6\n")
execute_process(COMMAND ${WORK_DIR}/build/calibrate_example ${WORK_DIR}/rows.txt fifty
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 2 OR NOT err MATCHES "NORM must be a number, got 'fifty'")
  message(FATAL_ERROR "calibrate_example FILE fifty: expected exit 2 and a usage error, got ${rc}:\n${out}\n${err}")
endif()
message(STATUS "calibrate_example FILE fifty: ${err}")
