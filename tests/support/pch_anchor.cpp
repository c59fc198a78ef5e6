// Compiled only to build the precompiled header every GoogleTest binary reuses (tests/
// CMakeLists.txt, palp_test_pch): gtest, OpenVDB, Eigen and the standard headers tests share.
