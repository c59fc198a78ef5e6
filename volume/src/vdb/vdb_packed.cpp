// Leaves packed as a mask-compressed .vdb stores them, and the file written from them.
#include "vdb/vdb_packed.h"

#include <blosc.h>
#include <fcntl.h>
#include <openvdb/io/Compression.h>
#include <openvdb/tree/Tree.h>
#include <openvdb/version.h>
#include <sys/uio.h>
#include <tbb/parallel_sort.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <boost/uuid/random_generator.hpp>
#include <boost/uuid/uuid_io.hpp>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <type_traits>
#include <utility>

#include "palp/base/atomic_file.h"
#include "palp/base/error.h"
#include "volume_info_fields.h"

namespace palp::volume::detail {

namespace {

/// OpenVDB's FloatTree (openvdb.h, which palp_volume_core does not include).
using FloatTree = openvdb::tree::Tree4<float, 5, 4, 3>::Type;
using LeafT = FloatTree::LeafNodeType;

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

/// Bytes appended as OpenVDB's writers stream them: values as they lie in memory (little
/// endian), strings as io::writeString (a 32-bit length, then the characters).
struct Bytes {
    std::string out;

    template <typename T>
    void raw(const T& value) {
        static_assert(std::is_trivially_copyable_v<T>);
        out.append(reinterpret_cast<const char*>(&value), sizeof value);
    }
    void string(const std::string& s) {
        raw(static_cast<std::uint32_t>(s.size()));
        out.append(s);
    }
};

/// A grid's metadata as MetaMap::writeMeta writes it: by name (a std::map's order), each its
/// name, its type's name and its value (a 32-bit size, then the bytes).
class MetaBytes {
  public:
    template <typename T>
    void add(const std::string& name, const T& value) {
        if constexpr (std::is_same_v<T, std::string>) {
            put(name, "string", value.data(), value.size());
        } else if constexpr (std::is_same_v<T, std::array<std::int32_t, 3>>) {
            put(name, "vec3i", value.data(), sizeof value);
        } else if constexpr (std::is_same_v<T, std::array<double, 3>>) {
            put(name, "vec3d", value.data(), sizeof value);
        } else if constexpr (std::is_same_v<T, double>) {
            put(name, "double", &value, sizeof value);
        } else if constexpr (std::is_same_v<T, float>) {
            put(name, "float", &value, sizeof value);
        } else if constexpr (std::is_same_v<T, std::int32_t>) {
            put(name, "int32", &value, sizeof value);
        } else {
            static_assert(std::is_same_v<T, std::int64_t>);
            put(name, "int64", &value, sizeof value);
        }
    }
    void put(const std::string& name, const char* type, const void* value, std::size_t n) {
        mMeta[name] = {type, std::string(static_cast<const char*>(value), n)};
    }
    void write(Bytes& b) const {
        b.raw(static_cast<std::uint32_t>(mMeta.size()));
        for (const auto& [name, typed] : mMeta) {
            b.string(name);
            b.string(typed.first);
            b.string(typed.second);  // Metadata::write: size, then value
        }
    }

  private:
    std::map<std::string, std::pair<std::string, std::string>> mMeta;
};

/// io::DelayedLoadMetadata's value for @p leafCount leaves whose metadata byte is
/// NO_MASK_OR_INACTIVE_VALS, no compressed sizes: the count, then the mask bytes as
/// compression::bloscCompress compresses them (LZ4 through Blosc at level 9, shuffled as 4-byte
/// values, one block; inputs of 48 bytes or less stored raw, shorter than 128 zero-padded to
/// it, and raw where Blosc does not make them smaller), then UINT32_MAX (no sizes); nothing
/// for no leaves.
std::string delayedLoadValue(std::size_t leafCount) {
    if (leafCount == 0) return {};
    constexpr std::size_t kMinimum = 48, kPad = 128;
    std::string mask(leafCount, static_cast<char>(openvdb::io::NO_MASK_OR_INACTIVE_VALS));
    std::string packed;
    if (leafCount > kMinimum) {
        std::string input = mask;
        if (input.size() < kPad) input.resize(kPad, '\0');
        packed.resize(input.size() + BLOSC_MAX_OVERHEAD);
        const int n =
            blosc_compress_ctx(9, 1, sizeof(float), input.size(), input.data(), packed.data(),
                               packed.size(), BLOSC_LZ4_COMPNAME, input.size(), 1);
        packed.resize(n > 0 && static_cast<std::size_t>(n) < leafCount ? static_cast<std::size_t>(n)
                                                                       : 0);
    }
    Bytes b;
    b.raw(static_cast<std::uint32_t>(leafCount));
    b.raw(static_cast<std::uint32_t>(packed.size()));
    b.out.append(packed.empty() ? mask : packed);
    b.raw(std::numeric_limits<std::uint32_t>::max());
    return std::move(b.out);
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
    using Node4 = FloatTree::RootNodeType::ChildNodeType::ChildNodeType;
    using Node5 = FloatTree::RootNodeType::ChildNodeType;
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
    t.memUsage = sizeof(FloatTree) + sizeof(FloatTree::RootNodeType) +
                 tops * internalNodeBytes<Node5>() + lowers * internalNodeBytes<Node4>() +
                 leaves.size() * (sizeof(LeafT) + LeafT::SIZE * sizeof(float));
    return t;
}

/// The file up to the buffers, as Archive::write writes it for one grid in a seekable file:
/// header, file metadata, the grid's descriptor (its three stream positions included: the
/// buffers, @p bufferBytes of them, follow the topology), compression, metadata, transform and
/// @p topology.
std::string filePrefix(const PackedGrid& grid, const Topology& topology, const PackedStats& stats,
                       std::size_t leafCount, std::uint64_t bufferBytes) {
    namespace io = openvdb::io;
    Bytes b;
    constexpr std::uint32_t kCompression = io::COMPRESS_ACTIVE_MASK;
    // Archive::writeHeader: magic, file format and library versions, "has grid offsets", UUID.
    b.raw(std::int64_t{openvdb::OPENVDB_MAGIC});
    b.raw(std::uint32_t{openvdb::OPENVDB_FILE_VERSION});
    b.raw(std::uint32_t{openvdb::OPENVDB_LIBRARY_MAJOR_VERSION});
    b.raw(std::uint32_t{openvdb::OPENVDB_LIBRARY_MINOR_VERSION});
    b.raw(char{1});
    b.out += boost::uuids::to_string(boost::uuids::random_generator()());  // as OpenVDB: random
    MetaBytes fileMeta;
    fileMeta.add("creator", std::string("palp"));
    fileMeta.write(b);
    b.raw(std::int32_t{1});  // one grid
    // Archive::writeGrid, for a grid whose name is unique and whose values are not halved:
    // GridDescriptor::writeHeader (name, type, no instance parent), then its stream positions
    // (grid, buffers, end), known once the topology's size is.
    b.string(kScanGridName);
    b.string("Tree_float_5_4_3");
    b.string("");
    const std::size_t offsetPos = b.out.size();
    b.out.append(3 * sizeof(std::int64_t), '\0');
    const auto gridPos = static_cast<std::int64_t>(b.out.size());
    b.raw(kCompression);  // setGridCompression: no ZIP to take away
    // The grid's metadata (its name, its VolumeInfo), then what OpenVDB adds: the delayed-load
    // masks, the file statistics and the compression in words.
    MetaBytes meta;
    meta.add("name", std::string(kScanGridName));
    forEachInfoField(grid.info,
                     [&](const char* name, const auto& value) { meta.add(name, value); });
    const std::string delayed = delayedLoadValue(leafCount);
    meta.put("file_delayed_load", "__delayedload", delayed.data(), delayed.size());
    const openvdb::CoordBBox& box = stats.box;
    meta.add("file_bbox_min",
             std::array<std::int32_t, 3>{box.min().x(), box.min().y(), box.min().z()});
    meta.add("file_bbox_max",
             std::array<std::int32_t, 3>{box.max().x(), box.max().y(), box.max().z()});
    meta.add("file_mem_bytes", static_cast<std::int64_t>(topology.memUsage));
    meta.add("file_voxel_count", static_cast<std::int64_t>(stats.activeVoxels));
    meta.add("file_compression", std::string("active values"));  // io::compressionToString
    meta.write(b);
    // Transform::write: the map's type, then ScaleTranslateMap::write (translation, scale,
    // voxel size, inverse scale, its square, half of it), as its constructor computes them.
    const StoredMap map = storedMap(grid.step, grid.lo);
    b.string(map.uniform ? "UniformScaleTranslateMap" : "ScaleTranslateMap");
    const auto vec = [&](const auto& f) {
        for (int a = 0; a < 3; ++a) b.raw(static_cast<double>(f(a)));
    };
    vec([&](int a) { return map.translation[a]; });
    vec([&](int a) { return map.scale[a]; });
    vec([&](int a) { return std::abs(map.scale[a]); });
    vec([&](int a) { return 1.0 / map.scale[a]; });
    vec([&](int a) { return (1.0 / map.scale[a]) * (1.0 / map.scale[a]); });
    vec([&](int a) { return (1.0 / map.scale[a]) / 2; });
    b.out += topology.bytes;
    const std::int64_t positions[3] = {gridPos, static_cast<std::int64_t>(b.out.size()),
                                       static_cast<std::int64_t>(b.out.size() + bufferBytes)};
    std::memcpy(b.out.data() + offsetPos, positions, sizeof positions);
    return std::move(b.out);
}

}  // namespace

StoredMap storedMap(const Eigen::Vector3d& step, const Eigen::Vector3d& lo) {
    StoredMap m{true, step, lo};
    if (step.x() == step.y() && step.y() == step.z()) return m;  // no simplification
    // simplify(AffineMap): translation = (0, 0, 0) * matrix, scale = (1, 1, 1) * matrix minus
    // it (Mat4's row-vector product: 1 * s + 1 * 0 + 1 * 0 + t), each as double arithmetic.
    for (int a = 0; a < 3; ++a) m.scale[a] = (step[a] + lo[a]) - lo[a];
    const auto near = [](double x, double y) { return !(std::abs(x - y) > 1e-15); };
    m.uniform = near(m.scale[0], m.scale[1]) && near(m.scale[0], m.scale[2]);
    if (m.uniform) m.scale = Eigen::Vector3d::Constant(m.scale[0]);
    return m;
}

char* packLeafBuffers(const std::uint64_t (&words)[8], const float* values, char* dst) noexcept {
    std::memcpy(dst, words, sizeof words);
    dst += sizeof words;
    *dst++ = static_cast<char>(openvdb::io::NO_MASK_OR_INACTIVE_VALS);
    for (unsigned w = 0; w < 8; ++w) {
        const float* row = values + w * 64;
        const std::uint64_t on = words[w];
        if (on == ~std::uint64_t{0}) {
            std::memcpy(dst, row, 64 * sizeof(float));
            dst += 64 * sizeof(float);
        } else if (on != 0) {
            // Every value stored, the pointer advanced past the active ones only: no branch per
            // value (the last stores land in the slack past the leaf or on values written next).
            for (unsigned i = 0; i < 64; ++i) {
                std::memcpy(dst, row + i, sizeof(float));
                dst += ((on >> i) & 1u) * sizeof(float);
            }
        }
    }
    return dst;
}

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

PackedStats writePackedVdb(const PackedGrid& grid, const PackedLeaves& packed,
                           const std::filesystem::path& path) {
    const std::vector<PackedLeaves::Leaf> leaves = packed.inTreeOrder();
    std::uint64_t bufferBytes = 0;
    for (const PackedLeaves::Leaf& leaf : leaves) bufferBytes += leaf.size;
    const Topology topology = topologyOf(leaves, grid.background);
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
