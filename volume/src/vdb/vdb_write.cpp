// Parallel compression of a float grid's leaf buffers for OpenVDB's archive writer.
#include "vdb/vdb_write.h"

#include <openvdb/io/io.h>

#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstring>
#include <memory>
#include <ostream>
#include <streambuf>
#include <vector>

#include "palp/base/parallel.h"

namespace palp::volume::detail {

namespace {

using LeafT = openvdb::FloatTree::LeafNodeType;

/// A chunk's bytes: grown without initialising what is appended (a std::string's resize()
/// zero-fills the bytes the leaf's values then overwrite), reused from batch to batch (cleared,
/// its capacity kept). At least kSlack bytes past the end are always allocated, so a leaf's
/// values can be compacted with a store per value, kept or not (appendMaskCompressedLeaf).
class ChunkBytes {
  public:
    static constexpr std::size_t kSlack = 64 * sizeof(float);

    void clear() noexcept { mSize = 0; }
    void reserve(std::size_t n) {
        if (n + kSlack <= mCapacity) return;
        auto grown = std::make_unique_for_overwrite<char[]>(n + kSlack);
        if (mSize > 0) std::memcpy(grown.get(), mData.get(), mSize);
        mData = std::move(grown);
        mCapacity = n + kSlack;
    }
    /// @p n more bytes, uninitialised, at the end; kSlack more writable past them.
    char* grow(std::size_t n) {
        if (mSize + n + kSlack > mCapacity) reserve(std::max(mSize + n, 2 * mCapacity));
        char* at = mData.get() + mSize;
        mSize += n;
        return at;
    }
    void append(const char* s, std::size_t n) { std::memcpy(grow(n), s, n); }
    const char* data() const noexcept { return mData.get(); }
    std::size_t size() const noexcept { return mSize; }

  private:
    std::unique_ptr<char[]> mData;
    std::size_t mSize = 0, mCapacity = 0;
};

/// An output stream buffer that appends to a chunk its owner keeps, for the leaves OpenVDB's
/// own writer writes.
class AppendBuf final : public std::streambuf {
  public:
    explicit AppendBuf(ChunkBytes& out) : mOut(out) {}

  protected:
    std::streamsize xsputn(const char* s, std::streamsize n) override {
        mOut.append(s, static_cast<std::size_t>(n));
        return n;
    }
    int_type overflow(int_type c) override {
        if (!traits_type::eq_int_type(c, traits_type::eof())) {
            const char ch = traits_type::to_char_type(c);
            mOut.append(&ch, 1);
        }
        return traits_type::not_eof(c);
    }

  private:
    ChunkBytes& mOut;
};

/// The bits of @p row's 64 values equal to @p background (==, as OpenVDB's MaskCompress
/// compares them: -0 equals 0, NaN equals nothing), four at a time.
inline std::uint64_t equalBits(const float* row, float background) noexcept {
    std::uint64_t eq = 0;
#ifdef __SSE2__
    const __m128 bg = _mm_set1_ps(background);
    for (unsigned j = 0; j < 16; ++j) {
        const auto bits =
            static_cast<unsigned>(_mm_movemask_ps(_mm_cmpeq_ps(_mm_loadu_ps(row + 4 * j), bg)));
        eq |= std::uint64_t{bits} << (4 * j);
    }
#else
    for (unsigned i = 0; i < 64; ++i) eq |= std::uint64_t{row[i] == background} << i;
#endif
    return eq;
}

/// Appends @p leaf's buffers to @p out as LeafNode::writeBuffers writes them for a stream whose
/// compression is COMPRESS_ACTIVE_MASK alone and whose values are not saved as half floats,
/// when every inactive value is @p background (what the resampler makes): the value mask, the
/// metadata byte NO_MASK_OR_INACTIVE_VALS and the active values in index order. Returns false,
/// appending nothing, for any other leaf (OpenVDB's own writer then writes it).
bool appendMaskCompressedLeaf(const LeafT& leaf, float background, ChunkBytes& out) {
    const LeafT::NodeMaskType& mask = leaf.getValueMask();
    const float* values = leaf.buffer().data();
    if (values == nullptr) return false;
    constexpr openvdb::Index kWords = LeafT::NodeMaskType::WORD_COUNT;
    std::uint64_t words[kWords];
    std::size_t active = 0;
    for (openvdb::Index w = 0; w < kWords; ++w) {
        words[w] = mask.getWord<std::uint64_t>(w);
        active += static_cast<std::size_t>(std::popcount(words[w]));
        // Every inactive value must be the background for the mask alone to restore it.
        if (words[w] != ~std::uint64_t{0} &&
            (equalBits(values + w * 64, background) | words[w]) != ~std::uint64_t{0})
            return false;
    }
    packLeafBuffers(words, values, out.grow(packedLeafBytes(active)));
    return true;
}

/// OpenVDB writes a grid as header, metadata, transform, topology (Archive::writeGrid) and then
/// the buffers through the virtual Grid::writeBuffers(): the root's children in table order,
/// each internal node's children in child-mask order, down to LeafNode::writeBuffers (value
/// mask, then the compressed values). The leaf iterator visits leaves in that same order, so
/// compressing runs of consecutive leaves into memory and writing them in order gives the
/// serial writer's bytes.
class ParallelWritingGrid final : public openvdb::FloatGrid {
  public:
    explicit ParallelWritingGrid(openvdb::FloatTree::Ptr tree) : openvdb::FloatGrid(tree) {}

    void writeBuffers(std::ostream& os) const override {
        std::vector<const LeafT*> leaves;
        leaves.reserve(tree().leafCount());
        for (auto it = tree().cbeginLeaf(); it; ++it) leaves.push_back(it.getLeaf());
        // The stream state the leaves read (compression flags, background, half floats), set
        // on @p os by the archive and the topology writer, copied to each chunk's stream.
        const openvdb::io::StreamMetadata state(os);
        const bool toHalf = saveFloatAsHalf();
        const void* background = openvdb::io::getGridBackgroundValuePtr(os);
        const std::uint32_t compression = openvdb::io::getDataCompression(os);
        // The common leaf written here directly (no stream, no temporary buffer per leaf).
        const bool direct = compression == openvdb::io::COMPRESS_ACTIVE_MASK && !toHalf;
        const float bg = background ? *static_cast<const float*>(background) : 0.0f;
        // Batches of chunks, each batch's chunks compressed in parallel into memory; while one
        // task writes a batch in order, the others compress the next one into the other set of
        // buffers (palp::parallelForEach, so ThreadSanitizer sees the fork and join).
        constexpr std::size_t kChunk = 64;  // leaves per chunk: ~130 KB before compression
        constexpr std::size_t kBatch = 32;  // chunks per batch: ~4 MB before compression
        std::vector<ChunkBytes> bytes[2] = {std::vector<ChunkBytes>(kBatch),
                                            std::vector<ChunkBytes>(kBatch)};
        // A leaf's buffers: its value mask, a metadata byte and at most its values (compression
        // adds a size field and never makes a chunk larger than that).
        for (auto& set : bytes)
            for (ChunkBytes& b : set)
                b.reserve(kChunk *
                          (sizeof(LeafT::NodeMaskType) + 16 + sizeof(float) * LeafT::SIZE));
        const auto compress = [&](ChunkBytes& out, std::size_t begin, std::size_t end) {
            out.clear();
            AppendBuf buffer(out);  // unbuffered: direct appends and the stream's interleave
            std::ostream chunk(&buffer);
            state.transferTo(chunk);
            // Not carried by StreamMetadata: the background that mask compression compares
            // inactive values with (set on os by the topology writer).
            openvdb::io::setGridBackgroundValuePtr(chunk, background);
            openvdb::io::setDataCompression(chunk, compression);
            for (std::size_t i = begin; i < end; ++i) {
                // The leaves lie scattered in memory, each node and buffer met once: the node
                // two ahead and the buffer of the next are fetched while this one is written.
                if (i + 2 < end) __builtin_prefetch(leaves[i + 2]);
                if (i + 1 < end) {
                    const char* next =
                        reinterpret_cast<const char*>(leaves[i + 1]->buffer().data());
                    if (next != nullptr)
                        for (int line = 0; line < 4; ++line) __builtin_prefetch(next + 64 * line);
                }
                if (!direct || !appendMaskCompressedLeaf(*leaves[i], bg, out))
                    leaves[i]->writeBuffers(chunk, toHalf);
            }
        };
        const auto writeSet = [&](const std::vector<ChunkBytes>& set, std::size_t chunks) {
            for (std::size_t c = 0; c < chunks; ++c)
                os.write(set[c].data(), static_cast<std::streamsize>(set[c].size()));
        };
        const std::size_t perBatch = kChunk * kBatch;
        std::size_t pending = 0;  // chunks of the previous batch, in bytes[!cur], not yet written
        int cur = 0;
        for (std::size_t first = 0; first < leaves.size(); first += perBatch) {
            const std::size_t chunks =
                std::min(kBatch, (leaves.size() - first + kChunk - 1) / kChunk);
            // Index 0 writes the previous batch (when there is one); 1..chunks compress this one.
            palp::parallelForEach(
                std::size_t{0}, chunks + 1,
                [&](std::size_t i) {
                    if (i == 0) {
                        writeSet(bytes[1 - cur], pending);
                        return;
                    }
                    const std::size_t begin = first + (i - 1) * kChunk;
                    compress(bytes[cur][i - 1], begin, std::min(begin + kChunk, leaves.size()));
                },
                std::size_t{1});
            pending = chunks;
            cur = 1 - cur;
        }
        writeSet(bytes[1 - cur], pending);
    }
};

}  // namespace

openvdb::FloatGrid::Ptr parallelWritingGrid(const openvdb::FloatGrid& source) {
    auto grid = std::make_shared<ParallelWritingGrid>(
        std::const_pointer_cast<openvdb::FloatTree>(source.constTreePtr()));
    // The same transform object (a copy could change the voxel size in its last bits).
    grid->setTransform(
        std::const_pointer_cast<openvdb::math::Transform>(source.constTransformPtr()));
    for (auto it = source.beginMeta(); it != source.endMeta(); ++it)
        grid->insertMeta(it->first, *it->second);
    return grid;
}

}  // namespace palp::volume::detail
