#include "palp/volume/from_memory.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <vector>

#include "formats/raw_data.h"
#include "formats/reader_util.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp::volume {
namespace {

std::string at(const std::string& name, const char* field, std::size_t i) {
    return name + ": " + field + "[" + std::to_string(i) + "]";
}

template <typename T>
void gather(const MemoryGrid& g, const std::array<std::int64_t, 3>& st, std::vector<float>& out) {
    const auto* base = static_cast<const unsigned char*>(g.data);
    std::size_t n = 0;
    for (std::int64_t k = 0; k < g.dims[2]; ++k) {
        for (std::int64_t j = 0; j < g.dims[1]; ++j) {
            const unsigned char* row = base + j * st[1] + k * st[2];
            for (std::int64_t i = 0; i < g.dims[0]; ++i) {
                T v;
                std::memcpy(&v, row + i * st[0], sizeof v);
                out[n++] = saturatingFloat(static_cast<double>(v));
            }
        }
    }
}

/// The byte strides to use (packed when all are 0), checked not to overlap.
std::array<std::int64_t, 3> checkedStrides(const MemoryGrid& g, std::int64_t element) {
    std::array<std::int64_t, 3> st = g.strides;
    if (st == std::array<std::int64_t, 3>{0, 0, 0}) {
        st = {element, element * g.dims[0], element * g.dims[0] * g.dims[1]};
        return st;  // dims were checked: the product fits
    }
    std::array<std::size_t, 3> order{0, 1, 2};
    for (std::size_t a = 0; a < 3; ++a) {
        if (g.dims[a] > 1 && st[a] <= 0) {
            throwExpected(at(g.name, "strides", a),
                          "a positive byte stride (dims[" + std::to_string(a) + "] is " +
                              std::to_string(g.dims[a]) + ")",
                          std::to_string(st[a]));
        }
    }
    std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
        return (g.dims[a] > 1 ? st[a] : 0) < (g.dims[b] > 1 ? st[b] : 0);
    });
    // Along the axes by increasing stride, each must step over the whole extent of the
    // previous ones (the smallest over one element), or two voxels share bytes.
    std::int64_t extent = element;  // bytes covered by the axes so far
    std::string covered = "the element size (" + std::to_string(element) + " bytes)";
    for (const std::size_t a : order) {
        if (g.dims[a] <= 1) continue;
        if (st[a] < extent) {
            throwExpected(at(g.name, "strides", a),
                          "at least " + std::to_string(extent) + " bytes (" + covered +
                              "; smaller strides make voxels overlap)",
                          std::to_string(st[a]));
        }
        if (st[a] > std::numeric_limits<std::int64_t>::max() / g.dims[a]) {
            throwExpected(
                at(g.name, "strides", a),
                "a stride whose extent (x dims[" + std::to_string(a) + "]) fits in 64 bits",
                std::to_string(st[a]));
        }
        extent = st[a] * g.dims[a];
        covered = "strides[" + std::to_string(a) + "] x dims[" + std::to_string(a) + "]";
    }
    return st;
}

/// The affine in LPS metres, checked like the readers' (finite, last row, then checkAffine).
void checkedAffine(const MemoryGrid& g, Eigen::Matrix3d& axes, Eigen::Vector3d& origin) {
    for (int r = 0; r < 4; ++r) {
        for (int c = 0; c < 4; ++c) {
            const double v = g.indexToWorld(r, c);
            const std::string field =
                g.name + ": index_to_world[" + std::to_string(r) + "][" + std::to_string(c) + "]";
            requireFinite(field, v);
            if (r == 3 && v != (c == 3 ? 1.0 : 0.0)) {
                throwExpected(
                    field, c == 3 ? "1 (the last row is 0 0 0 1)" : "0 (the last row is 0 0 0 1)",
                    formatValue(v));
            }
        }
    }
    Eigen::Matrix<double, 3, 4> m = g.indexToWorld.topRows<3>();
    if (g.frame == WorldFrame::RasMetres || g.frame == WorldFrame::RasMillimetres) {
        m.row(0) *= -1.0;  // RAS -> LPS
        m.row(1) *= -1.0;
    }
    if (g.frame == WorldFrame::LpsMillimetres || g.frame == WorldFrame::RasMillimetres) m *= 1e-3;
    axes = m.leftCols<3>();
    origin = m.col(3);
    try {
        detail::checkAffine(g.name, "index_to_world (axis columns)",
                            "index_to_world (axis columns)", "index_to_world (origin column)", axes,
                            origin);
    } catch (const FormatError& e) {
        throw ValueError(e.what());  // the caller's argument, not a file, is at fault
    }
}

}  // namespace

std::size_t valueTypeSize(ValueType type) {
    switch (type) {
        case ValueType::Int8:
        case ValueType::UInt8:
            return 1;
        case ValueType::Int16:
        case ValueType::UInt16:
            return 2;
        case ValueType::Int32:
        case ValueType::UInt32:
        case ValueType::Float32:
            return 4;
        case ValueType::Float64:
            return 8;
    }
    throw ValueError(
        "value type: expected int8, uint8, int16, uint16, int32, uint32, float32 or "
        "float64, found " +
        std::to_string(static_cast<int>(type)));
}

const char* valueTypeName(ValueType type) noexcept {
    switch (type) {
        case ValueType::Int8:
            return "int8";
        case ValueType::UInt8:
            return "uint8";
        case ValueType::Int16:
            return "int16";
        case ValueType::UInt16:
            return "uint16";
        case ValueType::Int32:
            return "int32";
        case ValueType::UInt32:
            return "uint32";
        case ValueType::Float32:
            return "float32";
        case ValueType::Float64:
            return "float64";
    }
    return nullptr;
}

SliceStack stackFromMemory(const MemoryGrid& g, std::uint64_t maxBytes) {
    if (!valueTypeName(g.type)) {
        throwExpected(g.name + ": type",
                      "int8, uint8, int16, uint16, int32, uint32, float32 or float64",
                      std::to_string(static_cast<int>(g.type)));
    }
    const auto element = static_cast<std::int64_t>(valueTypeSize(g.type));
    for (std::size_t a = 0; a < 3; ++a) {
        if (g.dims[a] <= 0 || g.dims[a] > std::numeric_limits<std::int32_t>::max()) {
            throwExpected(at(g.name, "dims", a), "a size in 1..2147483647",
                          std::to_string(g.dims[a]));
        }
    }
    checkedDataBytes(g.dims, sizeof(float), maxBytes, g.name);  // the floats palp will hold
    const std::array<std::int64_t, 3> st = checkedStrides(g, element);
    Eigen::Matrix3d axes;
    Eigen::Vector3d origin;
    checkedAffine(g, axes, origin);
    if (!g.data) throwExpected(g.name + ": data", "a pointer to the voxels", "NULL");

    std::vector<float> values(static_cast<std::size_t>(g.dims[0] * g.dims[1] * g.dims[2]));
    switch (g.type) {
        case ValueType::Int8:
            gather<std::int8_t>(g, st, values);
            break;
        case ValueType::UInt8:
            gather<std::uint8_t>(g, st, values);
            break;
        case ValueType::Int16:
            gather<std::int16_t>(g, st, values);
            break;
        case ValueType::UInt16:
            gather<std::uint16_t>(g, st, values);
            break;
        case ValueType::Int32:
            gather<std::int32_t>(g, st, values);
            break;
        case ValueType::UInt32:
            gather<std::uint32_t>(g, st, values);
            break;
        case ValueType::Float32:
            gather<float>(g, st, values);
            break;
        case ValueType::Float64:
            gather<double>(g, st, values);
            break;
    }
    SliceStack stack = stackFromAffine(values, g.dims, axes, origin, g.name);
    stack.info.sourceFormat = "memory";
    stack.info.sourceDescription = g.name;
    checkStackValues(stack);
    return stack;
}

Volume fromMemory(const MemoryGrid& grid, const ResampleOptions& options) {
    initialize();
    checkResampleOptions(options);
    return resample(stackFromMemory(grid), options);
}

}  // namespace palp::volume
