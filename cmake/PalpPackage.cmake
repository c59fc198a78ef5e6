# The installable package (issue 15 item 4): `cmake --install` puts the public headers, the
# module libraries, the palp tool, a CMake package (find_package(palp CONFIG): palp::base,
# palp::kernels, palp::volume, palp::fem, the haptics rooms palp::tissue, palp::rendering,
# palp::devices, palp::haptics (the servo runtime), palp::studies, palp::capi and
# palp::perception, and the umbrella palp::palp) and a pkg-config file for the C API (palp.pc:
# -lpalp_capi) under the prefix.
#
# The modules are shared libraries (palp_add_module), versioned here. Their private
# dependencies (Embree, GDCM, OpenJPEG, nifticlib, assimp, libpng, cairo, CHOLMOD) stay behind
# their DT_NEEDED entries; consumers need only what palp's public headers include: Eigen, OpenVDB,
# TBB and threads (palpConfig.cmake finds them).
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

# 0.x releases may break the ABI at every minor version, so the SONAME carries MAJOR.MINOR until
# 1.0 (libpalp_base.so.0.1), then MAJOR alone.
if(PROJECT_VERSION_MAJOR GREATER 0)
  set(PALP_SOVERSION ${PROJECT_VERSION_MAJOR})
  set(PALP_VERSION_COMPATIBILITY SameMajorVersion)
else()
  set(PALP_SOVERSION ${PROJECT_VERSION_MAJOR}.${PROJECT_VERSION_MINOR})
  set(PALP_VERSION_COMPATIBILITY SameMinorVersion)
endif()

# Installed binaries find palp's libraries next to themselves (libraries: $ORIGIN; the tool:
# $ORIGIN/../lib), so a prefix anywhere works without LD_LIBRARY_PATH. The build tree keeps
# CMake's absolute build RUNPATHs; as in every CMake project that installs, they end in ':' (room
# for the in-place rewrite at install), an empty entry the loader reads as the current directory.
file(RELATIVE_PATH palp_bin_to_lib /${CMAKE_INSTALL_BINDIR} /${CMAKE_INSTALL_LIBDIR})
set(palp_modules base kernels volume_core volume fem tissue rendering devices haptics studies capi perception)
set(palp_export_targets)
foreach(module ${palp_modules})
  set_target_properties(palp_${module} PROPERTIES
    VERSION ${PROJECT_VERSION} SOVERSION ${PALP_SOVERSION} EXPORT_NAME ${module}
    INSTALL_RPATH "$ORIGIN")
  target_include_directories(palp_${module} INTERFACE
    $<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}>)
  list(APPEND palp_export_targets palp_${module})
endforeach()
# palp::palp: every module, for programs that do not care which one they use.
add_library(palp_umbrella INTERFACE)
set_target_properties(palp_umbrella PROPERTIES EXPORT_NAME palp)
target_link_libraries(palp_umbrella INTERFACE palp_capi palp_studies palp_perception palp_haptics
  palp_devices palp_rendering palp_tissue palp_fem palp_volume palp_volume_core palp_kernels palp_base)
list(APPEND palp_export_targets palp_umbrella)

install(TARGETS ${palp_export_targets} EXPORT palpTargets
  LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
  ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
  RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
# palp_volume's DICOM library, opened at run time from beside libpalp_volume.so (not linked).
install(TARGETS palp_volume_dicom LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR})
foreach(dir kernels/base kernels volume fem haptics/tissue haptics/rendering haptics/devices
    haptics/runtime haptics/studies haptics/capi haptics/perception)
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/${dir}/include/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}
    FILES_MATCHING PATTERN "*.h")
endforeach()
if(TARGET palp)
  set_target_properties(palp PROPERTIES INSTALL_RPATH "$ORIGIN/${palp_bin_to_lib}")
  # The tool's own library and its commands module (tools/CMakeLists.txt), in the library
  # folder: not part of the exported package, no headers.
  set_target_properties(palp_tool PROPERTIES VERSION ${PROJECT_VERSION} SOVERSION ${PALP_SOVERSION}
    INSTALL_RPATH "$ORIGIN")
  set_target_properties(palp_tool_commands PROPERTIES INSTALL_RPATH "$ORIGIN")
  install(TARGETS palp RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
  install(TARGETS palp_tool palp_tool_commands LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR})
endif()
install(FILES ${PROJECT_SOURCE_DIR}/LICENSE DESTINATION ${CMAKE_INSTALL_DOCDIR})

# CMake package. Debian's FindOpenVDB is not on CMake's default module path: the config
# records the folder palp found it in.
find_file(PALP_FIND_OPENVDB FindOpenVDB.cmake PATHS ${CMAKE_MODULE_PATH} NO_DEFAULT_PATH)
mark_as_advanced(PALP_FIND_OPENVDB)
get_filename_component(PALP_OPENVDB_MODULE_DIR "${PALP_FIND_OPENVDB}" DIRECTORY)
set(PALP_CMAKE_DIR ${CMAKE_INSTALL_LIBDIR}/cmake/palp)
install(EXPORT palpTargets NAMESPACE palp:: DESTINATION ${PALP_CMAKE_DIR})
configure_package_config_file(${CMAKE_CURRENT_LIST_DIR}/palpConfig.cmake.in
  ${PROJECT_BINARY_DIR}/package/palpConfig.cmake INSTALL_DESTINATION ${PALP_CMAKE_DIR})
write_basic_package_version_file(${PROJECT_BINARY_DIR}/package/palpConfigVersion.cmake
  VERSION ${PROJECT_VERSION} COMPATIBILITY ${PALP_VERSION_COMPATIBILITY})
install(FILES ${PROJECT_BINARY_DIR}/package/palpConfig.cmake
  ${PROJECT_BINARY_DIR}/package/palpConfigVersion.cmake DESTINATION ${PALP_CMAKE_DIR})

# pkg-config, for the C API: relocatable (prefix from the .pc file's own folder), so an install
# with `cmake --install --prefix DIR` anywhere works.
set(PALP_PKGCONFIG_DIR ${CMAKE_INSTALL_LIBDIR}/pkgconfig)
file(RELATIVE_PATH PALP_PC_TO_PREFIX /${PALP_PKGCONFIG_DIR} /)
string(REGEX REPLACE "/$" "" PALP_PC_TO_PREFIX "${PALP_PC_TO_PREFIX}")
configure_file(${CMAKE_CURRENT_LIST_DIR}/palp.pc.in ${PROJECT_BINARY_DIR}/package/palp.pc @ONLY)
install(FILES ${PROJECT_BINARY_DIR}/package/palp.pc DESTINATION ${PALP_PKGCONFIG_DIR})
