#pragma once
// Grids that share a source grid's transform (internal).

#include <openvdb/openvdb.h>

namespace palp::volume::detail {

/// A new grid holding @p tree, @p source's transform and a copy of @p source's metadata (name
/// included). The transform is the same object, not a copy: Grid::copy() rebuilds the map and
/// can change the voxel size in its last bits, which a saved file must not.
inline openvdb::FloatGrid::Ptr gridWithTree(openvdb::FloatGrid& source,
                                            openvdb::FloatTree::Ptr tree) {
    openvdb::FloatGrid::Ptr grid = openvdb::FloatGrid::create(tree);
    grid->setTransform(source.transformPtr());
    for (auto it = source.beginMeta(); it != source.endMeta(); ++it)
        grid->insertMeta(it->first, *it->second);
    return grid;
}

}  // namespace palp::volume::detail
