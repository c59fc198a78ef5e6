#include "dicom/dicom_j2k.h"

#include <openjpeg.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <vector>

namespace palp::volume::dicom {

namespace {

constexpr std::uint16_t kSoc = 0xFF4F, kSiz = 0xFF51, kCod = 0xFF52, kCoc = 0xFF53, kSot = 0xFF90,
                        kSod = 0xFF93, kEoc = 0xFFD9;
constexpr unsigned char kPtermStyle = 0x10;  // code-block style bit: predictable termination
constexpr unsigned char kHtStyle = 0x40;     // HTJ2K code-blocks: no MQ coder to check

std::uint16_t be16(const std::vector<unsigned char>& b, std::size_t at) {
    return static_cast<std::uint16_t>(b[at] << 8 | b[at + 1]);
}

std::uint32_t be32(const std::vector<unsigned char>& b, std::size_t at) {
    return static_cast<std::uint32_t>(be16(b, at)) << 16 | be16(b, at + 2);
}

std::string hex(std::uint32_t v) {
    char buf[16];
    std::snprintf(buf, sizeof buf, "0x%04X", v);
    return buf;
}

/// Sets the PTERM bit in every COD and COC marker of @p cs (main and tile-part headers).
/// Returns what is wrong with the marker structure (empty when it walks from SOC to EOC);
/// sets @p htj2k when a code-block style declares HT code-blocks.
std::string declarePterm(std::vector<unsigned char>& cs, bool& htj2k) {
    htj2k = false;
    const std::size_t n = cs.size();
    if (n < 4 || be16(cs, 0) != kSoc || be16(cs, 2) != kSiz)
        return "a codestream that does not start with SOC and SIZ";
    std::size_t componentBytes = 1;  // Ccoc is 2 bytes when Csiz > 256
    std::size_t at = 2;
    while (at + 2 <= n) {
        const std::uint16_t marker = be16(cs, at);
        if (marker == kEoc) return {};
        if (at + 4 > n) break;
        if (marker == kSot) {
            if (at + 12 > n) break;
            const std::uint32_t psot = be32(cs, at + 6);
            // The tile-part header: markers up to SOD.
            std::size_t h = at + 2 + be16(cs, at + 2);
            while (h + 4 <= n && be16(cs, h) != kSod) {
                const std::uint16_t m = be16(cs, h);
                const std::size_t len = be16(cs, h + 2);
                if (m < 0xFF00 || len < 2)
                    return "marker " + hex(m) + " at byte " + std::to_string(h);
                if (m == kCod && h + 12 < n) cs[h + 12] |= kPtermStyle;
                if (m == kCoc && h + 8 + componentBytes < n)
                    cs[h + 8 + componentBytes] |= kPtermStyle;
                h += 2 + len;
            }
            if (psot == 0) return {};  // the last tile-part runs to EOC
            at += psot;
            continue;
        }
        const std::size_t len = be16(cs, at + 2);
        if (marker < 0xFF00 || len < 2 || at + 2 + len > n)
            return "marker " + hex(marker) + " at byte " + std::to_string(at);
        if (marker == kSiz && len >= 38) componentBytes = be16(cs, at + 38) > 256 ? 2 : 1;
        if (marker == kCod && len >= 12) {
            if (cs[at + 12] & kHtStyle) htj2k = true;
            cs[at + 12] |= kPtermStyle;
        }
        if (marker == kCoc && at + 8 + componentBytes < n) {
            if (cs[at + 8 + componentBytes] & kHtStyle) htj2k = true;
            cs[at + 8 + componentBytes] |= kPtermStyle;
        }
        at += 2 + len;
    }
    return "no EOC marker where the tile-parts end (byte " + std::to_string(at) + " of " +
           std::to_string(n) + ")";
}

/// An OpenJPEG input stream over a byte buffer.
struct Memory {
    const std::vector<unsigned char>* bytes;
    std::size_t at = 0;
};

OPJ_SIZE_T readMemory(void* out, OPJ_SIZE_T n, void* user) {
    auto* m = static_cast<Memory*>(user);
    if (m->at >= m->bytes->size()) return static_cast<OPJ_SIZE_T>(-1);
    const std::size_t k = std::min<std::size_t>(n, m->bytes->size() - m->at);
    std::memcpy(out, m->bytes->data() + m->at, k);
    m->at += k;
    return k;
}

OPJ_OFF_T skipMemory(OPJ_OFF_T n, void* user) {
    auto* m = static_cast<Memory*>(user);
    const auto size = static_cast<OPJ_OFF_T>(m->bytes->size());
    const OPJ_OFF_T to = std::clamp<OPJ_OFF_T>(static_cast<OPJ_OFF_T>(m->at) + n, 0, size);
    const OPJ_OFF_T moved = to - static_cast<OPJ_OFF_T>(m->at);
    m->at = static_cast<std::size_t>(to);
    return moved;
}

OPJ_BOOL seekMemory(OPJ_OFF_T to, void* user) {
    auto* m = static_cast<Memory*>(user);
    if (to < 0 || static_cast<std::size_t>(to) > m->bytes->size()) return OPJ_FALSE;
    m->at = static_cast<std::size_t>(to);
    return OPJ_TRUE;
}

/// What OpenJPEG said: the first error, and the first predictable-termination failure.
struct Events {
    std::string error, pterm;
};

std::string chomp(const char* msg) {
    std::string s = msg ? msg : "";
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
    return s;
}

void onError(const char* msg, void* user) {
    auto* e = static_cast<Events*>(user);
    if (e->error.empty()) e->error = chomp(msg);
}

void onWarning(const char* msg, void* user) {
    auto* e = static_cast<Events*>(user);
    // Other warnings (an unusual but legal marker, say) do not mean damaged pixels.
    if (e->pterm.empty() && msg && std::strstr(msg, "PTERM check failure")) e->pterm = chomp(msg);
}

void onInfo(const char*, void*) {}

}  // namespace

bool isLosslessJpeg2000(const std::string& uid) { return uid == "1.2.840.10008.1.2.4.90"; }

std::string checkLosslessJpeg2000(const unsigned char* data, std::size_t size) {
    std::vector<unsigned char> cs(data, data + size);
    bool htj2k = false;
    const std::string structure = declarePterm(cs, htj2k);
    if (!structure.empty()) return "unexpected " + structure;
    if (htj2k) return {};

    Memory memory{&cs};
    const std::unique_ptr<opj_stream_t, void (*)(opj_stream_t*)> stream(
        opj_stream_create(cs.size(), OPJ_TRUE), opj_stream_destroy);
    const std::unique_ptr<opj_codec_t, void (*)(opj_codec_t*)> codec(
        opj_create_decompress(OPJ_CODEC_J2K), opj_destroy_codec);
    if (!stream || !codec) return {};  // out of memory: GDCM's decode stands
    opj_stream_set_user_data(stream.get(), &memory, nullptr);
    opj_stream_set_user_data_length(stream.get(), cs.size());
    opj_stream_set_read_function(stream.get(), readMemory);
    opj_stream_set_skip_function(stream.get(), skipMemory);
    opj_stream_set_seek_function(stream.get(), seekMemory);
    Events events;
    opj_set_error_handler(codec.get(), onError, &events);
    opj_set_warning_handler(codec.get(), onWarning, &events);
    opj_set_info_handler(codec.get(), onInfo, nullptr);
    opj_dparameters_t parameters;
    opj_set_default_decoder_parameters(&parameters);
    if (!opj_setup_decoder(codec.get(), &parameters)) return {};

    opj_image_t* raw = nullptr;
    bool ok = opj_read_header(stream.get(), codec.get(), &raw) != 0;
    const std::unique_ptr<opj_image_t, void (*)(opj_image_t*)> image(raw, opj_image_destroy);
    ok = ok && opj_decode(codec.get(), stream.get(), image.get()) != 0;
    ok = ok && opj_end_decompress(codec.get(), stream.get()) != 0;
    if (!events.pterm.empty()) return "a damaged code-block (OpenJPEG: " + events.pterm + ")";
    if (!events.error.empty()) return "a damaged codestream (OpenJPEG: " + events.error + ")";
    if (!ok) return "a codestream OpenJPEG cannot decode";
    return {};
}

}  // namespace palp::volume::dicom
