#include "dicom/dicom_jpeg.h"

#include <array>
#include <cstdint>
#include <cstdio>
#include <vector>

namespace palp::volume::dicom {

namespace {

/// A Huffman table as ITU T.81 F.2.2.3 decodes with it (per code length the smallest and
/// largest code and where its values start), with a look-up of the codes of up to kLookBits
/// bits.
constexpr int kLookBits = 9;
struct HuffmanTable {
    bool defined = false;
    std::array<std::int32_t, 17> minCode{}, maxCode{}, valuePointer{};
    std::vector<std::uint8_t> values;
    /// For each kLookBits-bit prefix: code length << 8 | value, or 0 when the code is longer
    /// (or none).
    std::array<std::uint16_t, 1 << kLookBits> look{};
};

/// Builds @p t from the 16 code counts and the values of a DHT segment (T.81 Annex C).
bool buildTable(const std::uint8_t* counts, const std::uint8_t* values, std::size_t n,
                HuffmanTable& t) {
    t.values.assign(values, values + n);
    std::int32_t code = 0;
    std::size_t k = 0;
    for (int length = 1; length <= 16; ++length) {
        const auto l = static_cast<std::size_t>(length);
        const int count = counts[length - 1];
        t.maxCode[l] = -1;
        if (count > 0) {
            if (k + static_cast<std::size_t>(count) > n) return false;
            t.valuePointer[l] = static_cast<std::int32_t>(k);
            t.minCode[l] = code;
            for (int i = 0; i < count && length <= kLookBits; ++i) {
                const int first = (code + i) << (kLookBits - length);
                for (int j = 0; j < 1 << (kLookBits - length); ++j) {
                    t.look[static_cast<std::size_t>(first + j)] = static_cast<std::uint16_t>(
                        length << 8 | values[k + static_cast<std::size_t>(i)]);
                }
            }
            code += count;
            k += static_cast<std::size_t>(count);
            t.maxCode[l] = code - 1;
            if (code > (1 << length)) return false;  // more codes than the length allows
        }
        code <<= 1;
    }
    t.defined = k == n;
    return t.defined;
}

/// Reads the entropy-coded data of a scan, undoing byte stuffing (FF 00). At a marker or the
/// end of the data it goes on with zero bits, as libjpeg does, but counts them: a read that
/// reaches them has run out of data.
class BitReader {
  public:
    BitReader(const std::uint8_t* data, std::size_t size, std::size_t at)
        : mData(data), mSize(size), mAt(at) {}

    /// The next @p n (1-16) bits, not consumed.
    std::uint32_t peek(int n) {
        if (mCount < n) fill();
        return static_cast<std::uint32_t>(mAcc >> (64 - n));
    }

    /// Consumes @p n bits; false when they reach past the data (into a marker or the end).
    bool skip(int n) {
        mAcc <<= n;
        mCount -= n;
        mConsumed += static_cast<std::uint64_t>(n);
        return mConsumed <= mRealBits;
    }

    /// Drops the rest of the current byte and returns the file position of the next byte not
    /// consumed (where a marker should follow).
    std::size_t align() {
        mConsumed = (mConsumed + 7) / 8 * 8;
        const std::uint64_t consumedBytes = mConsumed / 8;
        std::size_t at = mStart;
        if (consumedBytes > 0 && consumedBytes <= mLoaded)
            at = mEnds[static_cast<std::size_t>((consumedBytes - 1) % mEnds.size())];
        return at;
    }

    /// The file position reached, for messages.
    std::size_t at() const { return mAt; }

  private:
    void fill() {
        while (mCount <= 56) {
            std::uint8_t b = 0;
            if (!mEnded && mAt < mSize && mData[mAt] != 0xFF) {
                b = mData[mAt];
                mAt += 1;
            } else if (!mEnded && mAt + 1 < mSize && mData[mAt] == 0xFF && mData[mAt + 1] == 0) {
                b = 0xFF;
                mAt += 2;
            } else {
                mEnded = true;
            }
            if (!mEnded) {
                mRealBits += 8;
                mEnds[static_cast<std::size_t>(mLoaded % mEnds.size())] = mAt;
                ++mLoaded;
            }
            mAcc |= static_cast<std::uint64_t>(b) << (56 - mCount);
            mCount += 8;
        }
    }

    const std::uint8_t* mData;
    std::size_t mSize, mAt, mStart = mAt;
    std::uint64_t mAcc = 0;
    int mCount = 0;
    bool mEnded = false;
    std::uint64_t mRealBits = 0, mConsumed = 0, mLoaded = 0;
    std::array<std::size_t, 16> mEnds{};  // file position after each of the last bytes loaded
};

/// One Huffman-coded value of table @p t (T.81 F.2.2.3); -1 for a code the table does not hold,
/// -2 when the code reaches past the data.
int decodeValue(BitReader& in, const HuffmanTable& t) {
    const std::uint16_t e = t.look[in.peek(kLookBits)];
    if (e != 0) return in.skip(e >> 8) ? (e & 0xFF) : -2;
    const std::uint32_t bits16 = in.peek(16);
    for (int length = kLookBits + 1; length <= 16; ++length) {
        const auto l = static_cast<std::size_t>(length);
        const auto code = static_cast<std::int32_t>(bits16 >> (16 - length));
        if (t.maxCode[l] >= 0 && code <= t.maxCode[l] && code >= t.minCode[l]) {
            if (!in.skip(length)) return -2;
            return t.values[static_cast<std::size_t>(t.valuePointer[l] + code - t.minCode[l])];
        }
    }
    return in.skip(16) ? -1 : -2;
}

std::string hex2(unsigned v) {
    char buf[8];
    std::snprintf(buf, sizeof buf, "%02X", v & 0xFFu);
    return buf;
}

/// The first marker at or after @p at (skipping fill bytes FF): its code, and in @p skipped the
/// bytes before it that are not part of it; -1 when the data ends first.
int nextMarker(const std::uint8_t* d, std::size_t size, std::size_t& at, std::size_t& skipped) {
    skipped = 0;
    while (at < size) {
        if (d[at] == 0xFF) {
            std::size_t p = at + 1;
            while (p < size && d[p] == 0xFF) ++p;
            if (p >= size) return -1;
            if (d[p] != 0x00) {
                at = p + 1;
                return d[p];
            }
            skipped += p + 1 - at;  // a stuffed FF 00: data, not a marker
            at = p + 1;
            continue;
        }
        ++skipped;
        ++at;
    }
    return -1;
}

std::uint32_t be16(const std::uint8_t* p) { return static_cast<std::uint32_t>(p[0] << 8 | p[1]); }

}  // namespace

bool isLosslessJpeg(const std::string& uid) {
    return uid == "1.2.840.10008.1.2.4.57" || uid == "1.2.840.10008.1.2.4.70";
}

std::string checkLosslessJpeg(const unsigned char* data, std::size_t size) {
    const std::uint8_t* d = data;
    const std::string ofStream = " of the " + std::to_string(size) + "-byte stream";
    if (size < 4 || d[0] != 0xFF || d[1] != 0xD8) return "no SOI marker (FFD8) at its start";
    std::array<HuffmanTable, 4> tables;
    std::uint32_t restartInterval = 0;
    int precision = 0, components = 0, predictor = 0, pointTransform = 0, tableId = 0;
    std::uint32_t lines = 0, columns = 0;
    bool sof3 = false;
    std::size_t at = 2;
    std::size_t scanAt = 0;
    while (scanAt == 0) {
        std::size_t skipped = 0;
        const std::size_t markerAt = at;
        const int marker = nextMarker(d, size, at, skipped);
        if (marker < 0) return "the end of the stream before any scan (no SOS marker)";
        if (skipped > 0) {
            return std::to_string(skipped) + " bytes that are no marker segment at byte " +
                   std::to_string(markerAt) + ofStream;
        }
        if (marker == 0xD9) return "an EOI marker before any scan (no SOS marker)";
        if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD7)) continue;  // no length
        if (at + 2 > size) return "a marker segment cut short at byte " + std::to_string(at);
        const std::uint32_t length = be16(d + at);
        if (length < 2 || at + length > size) {
            return "a marker segment FF" + hex2(static_cast<unsigned>(marker)) + " of " +
                   std::to_string(length) + " bytes at byte " + std::to_string(at) +
                   " that does not fit" + ofStream;
        }
        const std::uint8_t* seg = d + at + 2;
        const std::size_t n = length - 2;
        const bool otherFrame = (marker >= 0xC0 && marker <= 0xCF && marker != 0xC3 &&
                                 marker != 0xC4 && marker != 0xC8 && marker != 0xCC);
        if (otherFrame) return {};  // not process 14: not checked here
        if (marker == 0xC3) {
            if (n < 6) return "a SOF3 segment of " + std::to_string(length) + " bytes";
            precision = seg[0];
            lines = be16(seg + 1);
            columns = be16(seg + 3);
            components = seg[5];
            sof3 = true;
        } else if (marker == 0xC4) {
            std::size_t p = 0;
            while (p < n) {
                if (p + 17 > n) return "a DHT segment cut short at byte " + std::to_string(at);
                const int id = seg[p] & 0x0F;
                std::size_t count = 0;
                for (std::size_t i = 1; i <= 16; ++i) count += seg[p + i];
                if (p + 17 + count > n || id > 3 || count > 256)
                    return "a DHT segment cut short at byte " + std::to_string(at);
                HuffmanTable t;
                if (!buildTable(seg + p + 1, seg + p + 17, count, t))
                    return "a Huffman table that holds more codes than it can at byte " +
                           std::to_string(at);
                if ((seg[p] >> 4) == 0) tables[static_cast<std::size_t>(id)] = t;
                p += 17 + count;
            }
        } else if (marker == 0xDD) {
            if (n < 2) return "a DRI segment of " + std::to_string(length) + " bytes";
            restartInterval = be16(seg);
        } else if (marker == 0xDA) {
            if (!sof3) return {};
            if (n < 1 || n < 4 + 2u * seg[0]) return "an SOS segment cut short";
            if (seg[0] != 1 || components != 1) return {};  // colour: not checked here
            tableId = seg[2] >> 4;
            predictor = seg[3];
            pointTransform = seg[5] & 0x0F;
            scanAt = at + length;
        }
        at += length;
    }
    if (lines == 0) return {};  // height given later by a DNL marker: not checked here
    if (columns == 0) return "a frame of " + std::to_string(lines) + " lines of 0 samples";
    if (precision < 2 || precision > 16 || pointTransform >= precision)
        return "a precision of " + std::to_string(precision) + " bits with point transform " +
               std::to_string(pointTransform);
    if (predictor < 1 || predictor > 7)
        return "predictor " + std::to_string(predictor) + " (expected 1 to 7)";
    if (tableId > 3 || !tables[static_cast<std::size_t>(tableId)].defined)
        return "a scan using Huffman table " + std::to_string(tableId) + ", which no DHT defines";
    if (restartInterval % columns != 0) return {};  // restarts within a line: not checked here
    const HuffmanTable& table = tables[static_cast<std::size_t>(tableId)];

    const std::uint64_t total = std::uint64_t{lines} * columns;
    const std::int32_t limit = 1 << (precision - pointTransform);
    const bool checkRange = precision - pointTransform < 16;
    const std::int32_t initial = 1 << (precision - pointTransform - 1);
    std::vector<std::int32_t> previous(columns), current(columns);
    BitReader in(d, size, scanAt);
    std::uint32_t restartsSeen = 0;
    std::uint32_t firstLine = 0;  // the scan's first line, or the first after a restart
    std::uint64_t sample = 0;
    const auto where = [&](std::uint64_t s) {
        return " at sample " + std::to_string(s) + " of " + std::to_string(total) + " (line " +
               std::to_string(s / columns) + ", byte " + std::to_string(in.at()) + ofStream + ")";
    };
    for (std::uint32_t line = 0; line < lines; ++line) {
        if (restartInterval > 0 && line > 0 &&
            std::uint64_t{line} * columns % restartInterval == 0) {
            std::size_t p = in.align();
            std::size_t skipped = 0;
            const int marker = nextMarker(d, size, p, skipped);
            const int expected = 0xD0 + static_cast<int>(restartsSeen % 8);
            if (skipped > 0) {
                return std::to_string(skipped) + " extraneous bytes before the restart marker" +
                       where(sample);
            }
            if (marker != expected) {
                return "marker " +
                       (marker < 0 ? std::string("none (the end of the data)")
                                   : "FF" + hex2(static_cast<unsigned>(marker))) +
                       " where restart marker FF" + hex2(static_cast<unsigned>(expected)) +
                       " was due" + where(sample);
            }
            ++restartsSeen;
            in = BitReader(d, size, p);
            firstLine = line;
        }
        for (std::uint32_t col = 0; col < columns; ++col, ++sample) {
            const int category = decodeValue(in, table);
            if (category == -1) return "a bad Huffman code" + where(sample);
            if (category == -2) {
                return "the entropy-coded data ending (a marker or the end of the stream) "
                       "before the last sample" +
                       where(sample);
            }
            if (category > 16) {
                return "a difference of category " + std::to_string(category) + " (at most 16)" +
                       where(sample);
            }
            std::int32_t diff = 0;
            if (category == 16) {
                diff = 32768;
            } else if (category > 0) {
                const auto v = static_cast<std::int32_t>(in.peek(category));
                if (!in.skip(category)) {
                    return "the entropy-coded data ending (a marker or the end of the stream) "
                           "before the last sample" +
                           where(sample);
                }
                diff = v < (1 << (category - 1)) ? v - (1 << category) + 1 : v;
            }
            if (!checkRange) continue;  // every 16-bit sample is in range: no need to predict
            std::int32_t prediction;
            const std::int32_t ra = col > 0 ? current[col - 1] : 0;
            const std::int32_t rb = previous[col];
            const std::int32_t rc = col > 0 ? previous[col - 1] : 0;
            if (line == firstLine) {
                prediction = col == 0 ? initial : ra;
            } else if (col == 0) {
                prediction = rb;
            } else {
                switch (predictor) {
                    case 1:
                        prediction = ra;
                        break;
                    case 2:
                        prediction = rb;
                        break;
                    case 3:
                        prediction = rc;
                        break;
                    case 4:
                        prediction = ra + rb - rc;
                        break;
                    case 5:
                        prediction = ra + ((rb - rc) >> 1);
                        break;
                    case 6:
                        prediction = rb + ((ra - rc) >> 1);
                        break;
                    default:
                        prediction = (ra + rb) / 2;
                        break;
                }
            }
            const std::int32_t value = (prediction + diff) & 0xFFFF;
            if (value >= limit) {
                return "a sample of " + std::to_string(value) + ", beyond the " +
                       std::to_string(precision - pointTransform) + "-bit precision" +
                       where(sample);
            }
            current[col] = value;
        }
        previous.swap(current);
    }
    std::size_t p = in.align();
    const std::size_t scanEnd = p;
    std::size_t skipped = 0;
    const int marker = nextMarker(d, size, p, skipped);
    if (skipped > 0) {
        return std::to_string(skipped) +
               " extraneous bytes between the last sample and the next marker (at byte " +
               std::to_string(scanEnd) + ofStream + ")";
    }
    if (marker < 0) return "no EOI marker (FFD9) after the scan";
    if (marker >= 0xD0 && marker <= 0xD7) {
        return "a restart marker FF" + hex2(static_cast<unsigned>(marker)) +
               " after the last sample (at byte " + std::to_string(scanEnd) + ofStream + ")";
    }
    return {};
}

}  // namespace palp::volume::dicom
