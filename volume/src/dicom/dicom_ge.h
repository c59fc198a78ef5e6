#pragma once
// GE's phase-encoding polarity (internal), as dcm2niix derives it for its JSON sidecar's
// "PhaseEncodingPolarityGE". Neither dcm2niix nor palp changes pixels for it: GE stores the
// image as reconstructed, and the polarity tells a distortion-correction tool (FSL topup, ...)
// which way the phase was encoded.
#include <gdcmDataSet.h>

#include <filesystem>
#include <string>

namespace palp::volume::dicom {

/// The polarity of a GE EPI data set: "Flipped", "Unflipped", or "" when not GE, not EPI, or
/// not told. As dcm2niix v1.0.20241127 (nii_dicom.cpp): Rectilinear Phase Encode Reordering
/// (0018,9034) first (LINEAR: Flipped, REVERSE_LINEAR: Unflipped; RX27 on); else the user data
/// block (0043,102A): header offset (uint16 at byte 24), header version (float at the offset,
/// 5-40; from 25.002 the fields sit 0x4c bytes later and the view order 0x8c earlier), EPI
/// flag 0x800 of the int16 at +0x3a, polarity bit 0x4 of the int16 at +0x30, inverted when the
/// view order (int16 at +0x394) is bottom-up (2). Binary fields little endian. dcm2niix's
/// further inversion for alternate volumes of "pepolar" series (User data 12, (0019,10B3)) is
/// not applied.
std::string gePhaseEncodingPolarity(const gdcm::DataSet& ds);

/// gePhaseEncodingPolarity() of @p file, reading its header up to (0043,102A) only; "" when the
/// file cannot be read that far.
std::string gePhaseEncodingPolarity(const std::filesystem::path& file);

}  // namespace palp::volume::dicom
