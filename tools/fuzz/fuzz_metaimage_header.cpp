// libFuzzer target: palp's MetaImage header parser, then the whole MetaImage reader on the bytes
// written to a temporary file (small maxSourceBytes so a claimed size cannot exhaust memory),
// then resample() of what it accepted (a small lattice limit).
// Any palp::Error is an accepted outcome; crashes, sanitizer reports, leaks and other
// exceptions are findings.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>

#include "formats/formats.h"
#include "formats/header_parsers.h"
#include "palp/base/error.h"
#include "palp/volume/resample.h"

namespace {

const std::filesystem::path& scratchFile() {
    static const std::filesystem::path p = std::filesystem::temp_directory_path() /
                                           ("palp-fuzz-mha-" + std::to_string(::getpid()) + ".mha");
    return p;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::string_view text(reinterpret_cast<const char*>(data), size);
    try {
        const palp::volume::MetaImageHeader h =
            palp::volume::parseMetaImageHeader(text, "fuzz.mha");
        if (h.nDims != static_cast<int>(h.dimSize.size())) __builtin_trap();
        if (h.headerBytes > size) __builtin_trap();
    } catch (const palp::Error&) {
    }
    {
        std::ofstream out(scratchFile(), std::ios::binary | std::ios::trunc);
        out.write(text.data(), static_cast<std::streamsize>(text.size()));
    }
    palp::volume::ReadOptions options;
    options.maxSourceBytes = std::uint64_t{1} << 20;
    options.timePoint = 0;
    try {
        const palp::volume::SliceStack st = palp::volume::readMetaImage(scratchFile(), options);
        if (st.slices.empty()) __builtin_trap();
        // What the reader accepted goes on to the grid, as load() takes it: the geometry and
        // value checks must leave nothing that OpenVDB refuses in its own words (an
        // openvdb::Exception escaping here is a finding), and the lattice stays small.
        palp::volume::ResampleOptions resample;
        resample.maxVoxels = std::uint64_t{1} << 20;
        const palp::volume::Volume v = palp::volume::resample(st, resample);
        if (!v.grid) __builtin_trap();
    } catch (const palp::Error&) {
    }
    return 0;
}
