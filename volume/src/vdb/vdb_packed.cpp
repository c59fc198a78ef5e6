// Leaves packed as a mask-compressed .vdb stores them, and the file written from them.
#include "vdb/vdb_packed.h"

#include <fcntl.h>
#include <openvdb/io/DelayedLoadMetadata.h>
#include <openvdb/io/GridDescriptor.h>
#include <openvdb/io/io.h>
#include <sys/uio.h>
#include <tbb/parallel_sort.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <boost/uuid/random_generator.hpp>
#include <boost/uuid/uuid_io.hpp>
#include <cerrno>
#include <climits>
#include <cstring>
#include <sstream>
#include <type_traits>

#include "palp/base/atomic_file.h"
#include "palp/base/error.h"
#include "vdb/vdb_write.h"

namespace palp::volume::detail {

namespace {

using LeafT = openvdb::FloatTree::LeafNodeType;

/// Bytes a thread reserves at a time for its packed leaves, and what stays free past the last
/// leaf (packLeafBuffers may store one value past its end).
constexpr std::size_t kChunkBytes = std::size_t{4} << 20;
constexpr std::size_t kSlack = sizeof(float);

/// A 5-4-3 tree's nodes: the top internal nodes span 4096 voxels a side (log2 12), the lower
/// ones 128 (log2 7), the leaves 8 (log2 3).
constexpr int kTopLog2 = 12, kLowerLog2 = 7, kLeafLog2 = 3;

/// The leaf at @p c's place in a 5-4-3 tree's leaf order: the root's table sorts its top
/// nodes by origin (x, then y, then z); an internal node visits its children by offset (x
/// major, z fastest). So leaves sort by their top node's origin (high word: the three
/// coordinates' top-node indices, 21 bits each, offset so negative ones sort first), then by
/// their lower node's offset in it and their own offset in that (low word).
void treeOrder(const openvdb::Coord& c, std::uint64_t& high, std::uint64_t& low) noexcept {
    high = 0;
    low = 0;
    for (int axis = 0; axis < 3; ++axis) {
        const std::int64_t v = c[static_cast<std::size_t>(axis)];
        high = (high << 21) | static_cast<std::uint64_t>((v >> kTopLog2) + (std::int64_t{1} << 20));
        low = (low << 5) | static_cast<std::uint64_t>((v >> kLowerLog2) & 31);
    }
    for (int axis = 0; axis < 3; ++axis)
        low = (low << 4) |
              static_cast<std::uint64_t>((c[static_cast<std::size_t>(axis)] >> kLeafLog2) & 15);
}

/// Adds a leaf's active voxels and their box (LeafNode::evalActiveBoundingBox, voxel by voxel)
/// to @p stats: a leaf index is x << 6 | y << 3 | z, so word x of the mask holds row x, its
/// byte y, bit z.
void addLeafStats(const std::uint64_t (&words)[8], const openvdb::Coord& origin,
                  PackedStats& stats) {
    int xLo = 8, xHi = -1;
    std::uint64_t any = 0;
    for (int x = 0; x < 8; ++x) {
        const std::uint64_t w = words[static_cast<std::size_t>(x)];
        if (w == 0) continue;
        stats.activeVoxels += static_cast<std::uint64_t>(std::popcount(w));
        xLo = std::min(xLo, x);
        xHi = x;
        any |= w;
    }
    if (xHi < 0) return;
    unsigned ys = 0, zs = 0;
    for (unsigned y = 0; y < 8; ++y) {
        const auto row = static_cast<unsigned>((any >> (8 * y)) & 0xFF);
        if (row != 0) ys |= 1u << y;
        zs |= row;
    }
    stats.box.expand(openvdb::CoordBBox(
        origin + openvdb::Coord(xLo, std::countr_zero(ys), std::countr_zero(zs)),
        origin + openvdb::Coord(xHi, 31 - std::countl_zero(ys), 31 - std::countl_zero(zs))));
}

template <typename T>
void writeRaw(std::ostream& os, const T& value) {
    os.write(reinterpret_cast<const char*>(&value), sizeof value);
}

/// Writes the bytes of @p rest to @p fd in order, through short writes and interruptions.
void writeAll(int fd, std::vector<iovec> rest, const std::filesystem::path& path) {
    std::size_t first = 0;
    while (first < rest.size()) {
        const ssize_t n =
            ::writev(fd, rest.data() + first,
                     static_cast<int>(std::min<std::size_t>(rest.size() - first, IOV_MAX)));
        if (n < 0) {
            if (errno == EINTR) continue;
            throw IoError(path.string() + ": expected a writable location, found an error: " +
                          std::strerror(errno));
        }
        auto left = static_cast<std::size_t>(n);
        while (first < rest.size() && left >= rest[first].iov_len) left -= rest[first++].iov_len;
        if (left > 0) {
            rest[first].iov_base = static_cast<char*>(rest[first].iov_base) + left;
            rest[first].iov_len -= left;
        }
    }
}

/// The tree of @p leaves (in tree order): its topology as Tree::writeTopology writes it (a
/// stream whose compression is COMPRESS_ACTIVE_MASK alone) and what OpenVDB's file statistics
/// need of it.
struct Topology {
    std::string bytes;
    std::uint64_t memUsage = 0;  // tools::memUsage of the tree, every leaf's buffer allocated
};

/// tools::memUsage's count for one internal node of type N.
template <typename N>
std::uint64_t internalNodeBytes() {
    return N::NUM_VALUES * sizeof(typename N::UnionType) + 2 * N::NodeMaskType::memUsage() +
           sizeof(openvdb::Coord);
}

Topology topologyOf(const std::vector<PackedLeaves::Leaf>& leaves, float background) {
    using Node4 = openvdb::FloatTree::RootNodeType::ChildNodeType::ChildNodeType;
    using Node5 = openvdb::FloatTree::RootNodeType::ChildNodeType;
    constexpr std::size_t kLeafMask = LeafT::NodeMaskType::WORD_COUNT * sizeof(std::uint64_t);
    std::size_t tops = 0, lowers = 0;
    for (std::size_t i = 0; i < leaves.size(); ++i) {
        tops += i == 0 || leaves[i].orderHigh != leaves[i - 1].orderHigh;
        lowers += i == 0 || leaves[i].orderHigh != leaves[i - 1].orderHigh ||
                  (leaves[i].orderLow >> 12) != (leaves[i - 1].orderLow >> 12);
    }
    // An internal node: child mask, value mask (no tile active), then its tile values, all
    // inactive and the background (the child slots do not count): metadata
    // NO_MASK_OR_INACTIVE_VALS and no values. A top node is preceded by its origin.
    const std::size_t topBytes = 3 * sizeof(std::int32_t) + 2 * Node5::NodeMaskType::memUsage() + 1;
    const std::size_t lowerBytes = 2 * Node4::NodeMaskType::memUsage() + 1;
    Topology t;
    t.bytes.resize(sizeof(std::int32_t) + sizeof(float) + 2 * sizeof(openvdb::Index) +
                   tops * topBytes + lowers * lowerBytes + leaves.size() * kLeafMask);
    char* at = t.bytes.data();
    const auto put = [&](const void* data, std::size_t n) {
        std::memcpy(at, data, n);
        at += n;
    };
    const auto putRaw = [&](const auto& value) { put(&value, sizeof value); };
    const auto putNodeHead = [&](const auto& childMask) {
        using Mask = std::remove_cvref_t<decltype(childMask)>;
        for (openvdb::Index w = 0; w < Mask::WORD_COUNT; ++w)
            putRaw(childMask.template getWord<std::uint64_t>(w));  // NodeMask::save's words
        std::memset(at, 0, childMask.memUsage());
        at += childMask.memUsage();
        putRaw(static_cast<char>(openvdb::io::NO_MASK_OR_INACTIVE_VALS));
    };
    putRaw(std::int32_t{1});  // TreeBase::writeTopology: the buffer count
    putRaw(background);       // RootNode::writeTopology: background, tiles, children
    putRaw(openvdb::Index{0});
    putRaw(static_cast<openvdb::Index>(tops));
    std::size_t i = 0;
    while (i < leaves.size()) {
        // One top node: the run of leaves with its origin.
        std::size_t end = i;
        openvdb::util::NodeMask<5> topChildren;
        while (end < leaves.size() && leaves[end].orderHigh == leaves[i].orderHigh) {
            topChildren.setOn(static_cast<openvdb::Index>(leaves[end].orderLow >> 12));
            ++end;
        }
        const openvdb::Coord& c = leaves[i].origin;
        const std::int32_t top[3] = {c.x() & ~((1 << kTopLog2) - 1), c.y() & ~((1 << kTopLog2) - 1),
                                     c.z() & ~((1 << kTopLog2) - 1)};
        putRaw(top);
        putNodeHead(topChildren);
        while (i < end) {
            // One lower node: its leaves' masks after its head (each the first bytes of the
            // leaf's packed buffers, scattered in memory: fetched a few leaves ahead).
            std::size_t stop = i;
            openvdb::util::NodeMask<4> lowerChildren;
            while (stop < end && (leaves[stop].orderLow >> 12) == (leaves[i].orderLow >> 12)) {
                lowerChildren.setOn(static_cast<openvdb::Index>(leaves[stop].orderLow & 4095));
                ++stop;
            }
            putNodeHead(lowerChildren);
            for (; i < stop; ++i) {
                if (i + 8 < leaves.size()) __builtin_prefetch(leaves[i + 8].bytes);
                put(leaves[i].bytes, kLeafMask);
            }
        }
    }
    // tools::memUsage: the tree and its root, each internal node's table and masks and origin,
    // each leaf with its buffer.
    t.memUsage = sizeof(openvdb::FloatTree) + sizeof(openvdb::FloatTree::RootNodeType) +
                 tops * internalNodeBytes<Node5>() + lowers * internalNodeBytes<Node4>() +
                 leaves.size() * (sizeof(LeafT) + LeafT::SIZE * sizeof(float));
    return t;
}

/// The file up to the buffers, as Archive::write writes it for one grid in a seekable file:
/// header, file metadata, the grid's descriptor (its three stream positions included: the
/// buffers, @p bufferBytes of them, follow the topology), compression, metadata, transform and
/// @p topology.
std::string filePrefix(const openvdb::FloatGrid& grid, const Topology& topology,
                       const PackedStats& stats, std::size_t leafCount, std::uint64_t bufferBytes) {
    namespace io = openvdb::io;
    std::ostringstream os(std::ios::binary);
    const std::uint32_t compression = io::COMPRESS_ACTIVE_MASK;
    auto streamMeta = std::make_shared<io::StreamMetadata>();
    io::setStreamMetadataPtr(os, streamMeta, /*transfer=*/false);
    io::setDataCompression(os, compression);
    io::setWriteGridStatsMetadata(os, true);
    // Archive::writeHeader: magic, file format and library versions, "has grid offsets", UUID.
    writeRaw(os, std::int64_t{openvdb::OPENVDB_MAGIC});
    writeRaw(os, std::uint32_t{openvdb::OPENVDB_FILE_VERSION});
    writeRaw(os, std::uint32_t{openvdb::OPENVDB_LIBRARY_MAJOR_VERSION});
    writeRaw(os, std::uint32_t{openvdb::OPENVDB_LIBRARY_MINOR_VERSION});
    writeRaw(os, char{1});
    os << boost::uuids::to_string(boost::uuids::random_generator()());  // as OpenVDB: random
    openvdb::MetaMap fileMeta;
    fileMeta.insertMeta("creator", openvdb::StringMetadata("palp"));
    fileMeta.writeMeta(os);
    writeRaw(os, std::int32_t{1});
    // Archive::writeGrid, for a grid whose name is unique and whose values are not halved.
    io::GridDescriptor gd(grid.getName(), grid.type(), false);
    gd.writeHeader(os);
    const auto offsetPos = static_cast<std::size_t>(os.tellp());
    gd.writeStreamPos(os);
    gd.setGridPos(os.tellp());
    writeRaw(os, compression);  // setGridCompression: no ZIP to take away
    // The metadata OpenVDB adds: delayed-load masks (every leaf's metadata byte, the same
    // for every packed leaf), the file statistics and the compression in words.
    openvdb::MetaMap meta(static_cast<const openvdb::MetaMap&>(grid));
    io::DelayedLoadMetadata delayed;
    if (leafCount > 0) {
        delayed.resizeMask(leafCount);
        for (std::size_t i = 0; i < leafCount; ++i)
            delayed.setMask(
                i, static_cast<io::DelayedLoadMetadata::MaskType>(io::NO_MASK_OR_INACTIVE_VALS));
    }
    meta.insertMeta(openvdb::GridBase::META_FILE_DELAYED_LOAD, delayed);
    const openvdb::CoordBBox& box = stats.box;
    meta.insertMeta(openvdb::GridBase::META_FILE_BBOX_MIN,
                    openvdb::Vec3IMetadata(box.min().asVec3i()));
    meta.insertMeta(openvdb::GridBase::META_FILE_BBOX_MAX,
                    openvdb::Vec3IMetadata(box.max().asVec3i()));
    meta.insertMeta(openvdb::GridBase::META_FILE_MEM_BYTES,
                    openvdb::Int64Metadata(static_cast<std::int64_t>(topology.memUsage)));
    meta.insertMeta(openvdb::GridBase::META_FILE_VOXEL_COUNT,
                    openvdb::Int64Metadata(static_cast<std::int64_t>(stats.activeVoxels)));
    meta.insertMeta(openvdb::GridBase::META_FILE_COMPRESSION,
                    openvdb::StringMetadata(io::compressionToString(compression)));
    meta.writeMeta(os);
    grid.writeTransform(os);
    os.write(topology.bytes.data(), static_cast<std::streamsize>(topology.bytes.size()));
    gd.setBlockPos(os.tellp());
    gd.setEndPos(gd.getBlockPos() + static_cast<std::int64_t>(bufferBytes));
    std::string prefix = std::move(os).str();
    std::ostringstream pos(std::ios::binary);
    gd.writeStreamPos(pos);
    prefix.replace(offsetPos, 3 * sizeof(std::int64_t), std::move(pos).str());
    return prefix;
}

}  // namespace

void PackedLeaves::add(const openvdb::Coord& origin, const openvdb::util::NodeMask<3>& mask,
                       const float* values) {
    std::uint64_t words[8];
    std::size_t active = 0;
    for (unsigned w = 0; w < 8; ++w) {
        words[w] = mask.getWord<std::uint64_t>(w);
        active += static_cast<std::size_t>(std::popcount(words[w]));
    }
    const std::size_t size = packedLeafBytes(active);
    Local& local = mLocal.local();
    if (local.left < size) {
        local.chunks.push_back(std::make_unique_for_overwrite<char[]>(kChunkBytes + kSlack));
        local.at = local.chunks.back().get();
        local.left = kChunkBytes;
    }
    packLeafBuffers(words, values, local.at);
    addLeafStats(words, origin, local.stats);
    Leaf leaf{origin, local.at, size, 0, 0};
    treeOrder(origin, leaf.orderHigh, leaf.orderLow);
    local.leaves.push_back(leaf);
    local.at += size;
    local.left -= size;
}

PackedStats PackedLeaves::stats() const {
    PackedStats out;
    for (const Local& local : mLocal) {
        out.activeVoxels += local.stats.activeVoxels;
        out.box.expand(local.stats.box);
    }
    return out;
}

std::vector<PackedLeaves::Leaf> PackedLeaves::inTreeOrder() const {
    std::vector<Leaf> all;
    std::size_t n = 0;
    for (const Local& local : mLocal) n += local.leaves.size();
    all.reserve(n);
    for (const Local& local : mLocal)
        all.insert(all.end(), local.leaves.begin(), local.leaves.end());
    tbb::parallel_sort(all.begin(), all.end(), [](const Leaf& a, const Leaf& b) {
        return a.orderHigh != b.orderHigh ? a.orderHigh < b.orderHigh : a.orderLow < b.orderLow;
    });
    return all;
}

PackedStats writePackedVdb(const openvdb::FloatGrid& grid, const PackedLeaves& packed,
                           const std::filesystem::path& path) {
    const std::vector<PackedLeaves::Leaf> leaves = packed.inTreeOrder();
    std::uint64_t bufferBytes = 0;
    for (const PackedLeaves::Leaf& leaf : leaves) bufferBytes += leaf.size;
    const Topology topology = topologyOf(leaves, grid.background());
    const PackedStats stats = packed.stats();
    const std::string prefix = filePrefix(grid, topology, stats, leaves.size(), bufferBytes);

    AtomicFile out(path, "volume");
    const int fd = ::open(out.tempPath().c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
    if (fd < 0) {
        throw IoError(path.string() +
                      ": expected a writable location, found an error: " + std::strerror(errno));
    }
    try {
        // The prefix, then the leaves' bytes, runs of leaves adjacent in memory as one piece.
        std::vector<iovec> pieces;
        pieces.reserve(leaves.size() + 1);
        pieces.push_back({const_cast<char*>(prefix.data()), prefix.size()});
        for (const PackedLeaves::Leaf& leaf : leaves) {
            iovec& last = pieces.back();
            if (pieces.size() > 1 && static_cast<char*>(last.iov_base) + last.iov_len == leaf.bytes)
                last.iov_len += leaf.size;
            else
                pieces.push_back({const_cast<char*>(leaf.bytes), leaf.size});
        }
        writeAll(fd, std::move(pieces), path);
    } catch (...) {
        ::close(fd);
        throw;
    }
    if (::close(fd) != 0) {
        throw IoError(path.string() +
                      ": expected a writable location, found an error: " + std::strerror(errno));
    }
    out.commit();
    return stats;
}

}  // namespace palp::volume::detail
