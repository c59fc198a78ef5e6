# One INTERFACE target carries palp's warnings and sanitizer flags; every palp target links it.
add_library(palp_options INTERFACE)
add_library(palp::options ALIAS palp_options)
target_compile_options(palp_options INTERFACE
  -Wall -Wextra -Wpedantic -Wshadow -Wconversion -Wsign-conversion
  $<$<BOOL:${PALP_WARNINGS_AS_ERRORS}>:-Werror>)
if(PALP_SANITIZE)
  target_compile_options(palp_options INTERFACE -fsanitize=${PALP_SANITIZE} -fno-omit-frame-pointer
    -fno-sanitize-recover=all)
  target_link_options(palp_options INTERFACE -fsanitize=${PALP_SANITIZE})
  # GCC's -Wmaybe-uninitialized reports false positives once sanitizer instrumentation changes
  # inlining (e.g. copies of std::optional<Eigen::Vector3d>); the Release build keeps it.
  if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
    target_compile_options(palp_options INTERFACE -Wno-maybe-uninitialized)
  endif()
endif()
# Fuzzing (preset 'fuzz', clang): instrument every palp library for libFuzzer coverage and
# ASan/UBSan; the fuzz executables themselves add -fsanitize=fuzzer (tools/fuzz).
if(PALP_BUILD_FUZZERS)
  target_compile_options(palp_options INTERFACE -fsanitize=fuzzer-no-link,address,undefined
    -fno-omit-frame-pointer -fno-sanitize-recover=all)
  target_link_options(palp_options INTERFACE -fsanitize=address,undefined)
endif()

# Adds a palp module: MODULE/include is public, sources listed by the caller. Modules are shared
# libraries (versioned and installed by PalpPackage.cmake). SHARED is explicit: they always were
# shared, but only because Debian's FindOpenVDB sets BUILD_SHARED_LIBS ON in the caller's scope.
function(palp_add_module name)
  cmake_parse_arguments(ARG "" "" "SOURCES;PUBLIC_DEPS;PRIVATE_DEPS" ${ARGN})
  add_library(palp_${name} SHARED ${ARG_SOURCES})
  add_library(palp::${name} ALIAS palp_${name})
  target_include_directories(palp_${name} PUBLIC
    $<BUILD_INTERFACE:${CMAKE_CURRENT_SOURCE_DIR}/include>)
  target_link_libraries(palp_${name} PUBLIC ${ARG_PUBLIC_DEPS} PRIVATE palp::options ${ARG_PRIVATE_DEPS})
  set_target_properties(palp_${name} PROPERTIES POSITION_INDEPENDENT_CODE ON)
  # Every symbol a module uses must come from the libraries it links (-z defs), so a room that
  # calls into a room above it fails to link instead of loading by luck. Not under sanitizers or
  # the fuzz build, whose runtimes resolve their symbols from the executable.
  if(NOT PALP_SANITIZE AND NOT PALP_BUILD_FUZZERS)
    target_link_options(palp_${name} PRIVATE LINKER:-z,defs)
  endif()
  palp_unity(palp_${name})
endfunction()

# With PALP_UNITY_BUILD, compiles a target's sources in batches of PALP_UNITY_BATCH_SIZE (the
# library modules, the palp tool, the Python extension): each batch parses OpenVDB's and Eigen's
# headers once. A batch needs one definition per name across its sources, anonymous namespaces
# included.
function(palp_unity target)
  if(PALP_UNITY_BUILD)
    set_target_properties(${target} PROPERTIES UNITY_BUILD ON
                                               UNITY_BUILD_BATCH_SIZE ${PALP_UNITY_BATCH_SIZE})
    # A batch includes the sources as headers, so a member whose type lives in a source's
    # anonymous namespace draws GCC's header-only warning; it is no hazard within one file.
    target_compile_options(${target} PRIVATE -Wno-subobject-linkage)
  endif()
endfunction()
