// The definitions that openvdb_float_grid.h declares extern (see there).
#include <openvdb/openvdb.h>

template class openvdb::v10_0::tree::InternalNode<openvdb::v10_0::tree::LeafNode<float, 3>, 4>;
template class openvdb::v10_0::tree::InternalNode<
    openvdb::v10_0::tree::InternalNode<openvdb::v10_0::tree::LeafNode<float, 3>, 4>, 5>;
template class openvdb::v10_0::tree::Tree<openvdb::FloatTree::RootNodeType>;
template class openvdb::v10_0::Grid<openvdb::FloatTree>;
