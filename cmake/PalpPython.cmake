# Finds what the Python bindings need and sets PALP_BUILD_PYTHON's default.
#
# Python is Debian's /usr/bin/python3 (it sees Debian's numpy and pyopenvdb), not whatever
# python3 comes first on PATH (a pyenv shim on developer machines): Python3_EXECUTABLE is
# preset to it when it exists; pass -DPython3_EXECUTABLE=... to choose another.
set(palp_python_default OFF)
if(NOT PALP_SANITIZE AND NOT PALP_BUILD_FUZZERS)
  if(NOT DEFINED Python3_EXECUTABLE AND EXISTS /usr/bin/python3)
    set(Python3_EXECUTABLE /usr/bin/python3 CACHE FILEPATH "Python of the palp module and its tests")
  endif()
  find_package(Python3 COMPONENTS Interpreter Development.Module QUIET)
  if(Python3_FOUND)
    # Debian ships pybind11Config.cmake in /usr/lib/cmake/pybind11; with Python3 found first it
    # uses FindPython3's targets (pybind11NewTools).
    find_package(pybind11 CONFIG QUIET)
    if(pybind11_FOUND)
      set(palp_python_default ON)
    endif()
  endif()
endif()
option(PALP_BUILD_PYTHON "Build the palp Python module (needs pybind11 and Python headers)"
  ${palp_python_default})
if(PALP_BUILD_PYTHON AND NOT pybind11_FOUND)
  find_package(Python3 COMPONENTS Interpreter Development.Module REQUIRED)
  find_package(pybind11 CONFIG REQUIRED)
endif()
