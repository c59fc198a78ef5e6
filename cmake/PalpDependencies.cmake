# Every dependency is a Debian bookworm package installed by tools/setup.sh.
# Third-party targets are imported, so their include directories are SYSTEM and their warnings
# are not ours.
list(APPEND CMAKE_MODULE_PATH /usr/lib/x86_64-linux-gnu/cmake/OpenVDB)  # Debian's FindOpenVDB
find_package(OpenVDB REQUIRED)          # OpenVDB::openvdb (needs libboost-iostreams-dev)
find_package(TBB REQUIRED)              # TBB::tbb
find_package(Eigen3 3.4 REQUIRED NO_MODULE)
find_package(embree 3 REQUIRED)         # embree
find_package(GDCM REQUIRED)             # gdcmMSFF and friends
find_package(ZLIB REQUIRED)
find_package(PNG REQUIRED)              # PNG::PNG (map images, haptics)
find_package(CLI11 REQUIRED)
find_package(nlohmann_json REQUIRED)
find_package(Threads REQUIRED)

# Debian's NIFTIConfig.cmake points at a library that does not exist; find nifticlib directly.
find_library(PALP_NIFTI2_LIB nifti2 REQUIRED)
find_library(PALP_ZNZ_LIB znz REQUIRED)
find_path(PALP_NIFTI_INCLUDE_DIR nifti2_io.h PATH_SUFFIXES nifti REQUIRED)
add_library(palp_nifti INTERFACE)
target_include_directories(palp_nifti SYSTEM INTERFACE ${PALP_NIFTI_INCLUDE_DIR})
target_link_libraries(palp_nifti INTERFACE ${PALP_NIFTI2_LIB} ${PALP_ZNZ_LIB} ZLIB::ZLIB m)

# GDCM's config exports plain target names and an include dir variable.
add_library(palp_gdcm INTERFACE)
target_include_directories(palp_gdcm SYSTEM INTERFACE ${GDCM_INCLUDE_DIRS})
target_link_libraries(palp_gdcm INTERFACE gdcmMSFF gdcmDSED gdcmCommon)

# OpenJPEG (the library GDCM decodes JPEG 2000 with): palp asks it for the damage check GDCM
# does not (volume/src/dicom/dicom_j2k.h). No CMake config is needed; find it directly.
find_path(PALP_OPENJPEG_INCLUDE_DIR openjpeg.h PATH_SUFFIXES openjpeg-2.5 REQUIRED)
find_library(PALP_OPENJP2_LIB openjp2 REQUIRED)
add_library(palp_openjpeg INTERFACE)
target_include_directories(palp_openjpeg SYSTEM INTERFACE ${PALP_OPENJPEG_INCLUDE_DIR})
target_link_libraries(palp_openjpeg INTERFACE ${PALP_OPENJP2_LIB})

# cairo 1.16 (map figures drawn as PNG, haptics) has no CMake config; find it directly.
find_library(PALP_CAIRO_LIB cairo REQUIRED)
find_path(PALP_CAIRO_INCLUDE_DIR cairo.h PATH_SUFFIXES cairo REQUIRED)
add_library(palp_cairo INTERFACE)
target_include_directories(palp_cairo SYSTEM INTERFACE ${PALP_CAIRO_INCLUDE_DIR})
target_link_libraries(palp_cairo INTERFACE ${PALP_CAIRO_LIB})

# CHOLMOD (SuiteSparse 5.12) has no CMake config.
find_library(PALP_CHOLMOD_LIB cholmod REQUIRED)
find_path(PALP_CHOLMOD_INCLUDE_DIR cholmod.h PATH_SUFFIXES suitesparse REQUIRED)

if(PALP_BUILD_TESTS)
  find_package(GTest REQUIRED)
endif()
if(PALP_BUILD_BENCH)
  find_package(benchmark REQUIRED)
endif()
