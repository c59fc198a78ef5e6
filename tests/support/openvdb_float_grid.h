// The float grid's classes, compiled once for all the tests (openvdb_float_grid.cpp, in
// palp_test_support) instead of in every test source: each test makes FloatGrids, and without
// these declarations each one compiled the whole tree (Tree, its internal nodes, Grid: about 15 s
// of a heavy test's 35 s at -O3). OpenVDB 10 declares its tools' instantiations this way but not
// the tree's. The root and leaf nodes stay implicit: OpenVDB 10 cannot instantiate every member
// of those for float. Included by the tests' precompiled header (release build only).
#pragma once

#include <openvdb/openvdb.h>

extern template class openvdb::v10_0::tree::InternalNode<openvdb::v10_0::tree::LeafNode<float, 3>,
                                                         4>;
extern template class openvdb::v10_0::tree::InternalNode<
    openvdb::v10_0::tree::InternalNode<openvdb::v10_0::tree::LeafNode<float, 3>, 4>, 5>;
extern template class openvdb::v10_0::tree::Tree<openvdb::FloatTree::RootNodeType>;
extern template class openvdb::v10_0::Grid<openvdb::FloatTree>;
