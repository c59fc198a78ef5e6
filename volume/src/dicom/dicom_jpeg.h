#pragma once
// Damage in lossless JPEG pixel data (internal). GDCM decodes JPEG Lossless (ITU T.81 process
// 14) through its own copy of libjpeg, whose damage reports are warnings: libjpeg prints the
// first to stderr, substitutes zeros and goes on, and GDCM accepts a stream with one warning.
// Measured from outside palp: one flipped byte changed 52 % of a series' voxels with only
// "Corrupt JPEG data" on stderr, and a byte changed every 4 KiB ("bad Huffman code") still gave
// a grid, exit 0. The warnings cannot be heard through GDCM (its error manager is internal to
// the codec), so palp walks each lossless codestream itself (see checkLosslessJpeg).
#include <cstddef>
#include <string>

namespace palp::volume::dicom {

/// Whether the transfer syntax @p uid is lossless JPEG, whose codestreams checkLosslessJpeg
/// applies to: JPEG Lossless, Non-Hierarchical (Process 14), 1.2.840.10008.1.2.4.57, and its
/// First-Order Prediction selection value 1 form, 1.2.840.10008.1.2.4.70.
bool isLosslessJpeg(const std::string& uid);

/// What is wrong with the lossless JPEG codestream @p data (@p size bytes, from SOI); empty when
/// nothing is, or when the stream is of a kind the check does not read (not SOF3, more than one
/// component, a height given by a DNL marker).
///
/// The check decodes the entropy-coded data as libjpeg does, without keeping the samples: one
/// Huffman-coded difference per sample, restart markers where DRI puts them, and reports every
/// condition libjpeg only warns of: a code no table holds ("bad Huffman code"), a marker or the
/// end of the data before the frame's last sample ("premature end of data segment"), bytes
/// between the last sample and the next marker ("extraneous bytes before marker"), a missing or
/// misnumbered restart marker; and, as libjpeg does not, a reconstructed sample outside the
/// frame's precision. A changed bit that leaves the code in step (inside a difference's extra
/// bits) changes samples without any of these: no check finds it.
std::string checkLosslessJpeg(const unsigned char* data, std::size_t size);

}  // namespace palp::volume::dicom
