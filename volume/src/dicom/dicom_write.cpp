// DICOM series writer (GDCM): one single-frame CT/MR image per slice, uint16 storage.
#include <gdcmAttribute.h>
#include <gdcmDataElement.h>
#include <gdcmDataSet.h>
#include <gdcmFile.h>
#include <gdcmImage.h>
#include <gdcmImageHelper.h>
#include <gdcmImageWriter.h>
#include <gdcmMediaStorage.h>
#include <gdcmPhotometricInterpretation.h>
#include <gdcmPixelFormat.h>
#include <gdcmTransferSyntax.h>
#include <gdcmUIDGenerator.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <ctime>
#include <string>
#include <system_error>
#include <vector>

#include "dicom/dicom_series.h"
#include "palp/base/atomic_file.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/volume/dicom.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace {

std::string num(double v) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.10g", v);
    return buf;
}

// Adds a string element, padded to even length as DICOM requires.
void setString(gdcm::DataSet& ds, std::uint16_t group, std::uint16_t element, gdcm::VR vr,
               std::string value) {
    if (value.size() % 2 != 0) value.push_back(vr == gdcm::VR::UI ? '\0' : ' ');
    gdcm::DataElement de(gdcm::Tag(group, element));
    de.SetVR(vr);
    de.SetByteValue(value.data(), static_cast<std::uint32_t>(value.size()));
    ds.Replace(de);
}

std::string uid(gdcm::UIDGenerator& gen) {
    const char* u = gen.Generate();
    if (u == nullptr) throw IoError("DICOM writer: expected a generated UID, found none");
    return std::string(u);
}

// Removes what a failed write left behind.
struct Cleanup {
    std::vector<fs::path> paths;
    fs::path createdDir;
    bool armed = true;
    ~Cleanup() {
        if (!armed) return;
        std::error_code ec;
        for (const fs::path& p : paths) fs::remove(p, ec);
        if (!createdDir.empty()) fs::remove(createdDir, ec);
    }
};

/// Checks @p stack and @p options before the first byte is written.
/// @throw ValueError naming the slice (or @p where) and the offending value.
void checkWritable(const SliceStack& stack, const DicomWriteOptions& options,
                   const std::string& where) {
    if (stack.slices.empty()) throwExpected(where, "at least one slice to write", "none");
    if (!(options.rescaleSlope > 0) || !std::isfinite(options.rescaleSlope) ||
        !std::isfinite(options.rescaleIntercept)) {
        throwExpected(
            where, "a positive, finite rescale slope and a finite intercept",
            "slope " + num(options.rescaleSlope) + ", intercept " + num(options.rescaleIntercept));
    }
    if (options.modality.empty()) throwExpected(where, "a modality", "an empty string");
    const Slice& first = stack.slices.front();
    const double lo = options.rescaleIntercept;
    const double hi = options.rescaleIntercept + 65535.0 * options.rescaleSlope;
    for (std::size_t k = 0; k < stack.slices.size(); ++k) {
        const Slice& s = stack.slices[k];
        const std::string name = s.source.empty() ? "slice " + std::to_string(k) : s.source;
        if (s.cols <= 0 || s.rows <= 0 || s.cols > 65535 || s.rows > 65535 ||
            s.values.size() !=
                static_cast<std::size_t>(s.cols) * static_cast<std::size_t>(s.rows)) {
            throw ValueError(
                name + ": expected 1 to 65535 rows and columns with rows * columns values, found " +
                std::to_string(s.cols) + "x" + std::to_string(s.rows) + " with " +
                std::to_string(s.values.size()) + " values");
        }
        if (s.cols != first.cols || s.rows != first.rows) {
            throw ValueError(name + ": expected " + std::to_string(first.cols) + "x" +
                             std::to_string(first.rows) + " pixels like the first slice, found " +
                             std::to_string(s.cols) + "x" + std::to_string(s.rows));
        }
        if (!(s.colStep.norm() > 0) || !(s.rowStep.norm() > 0) || !s.position.allFinite() ||
            !s.colStep.allFinite() || !s.rowStep.allFinite()) {
            throw ValueError(
                name +
                ": expected finite position and non-zero steps, found a degenerate geometry");
        }
        for (float v : s.values) {
            // Values are rounded to the nearest stored integer, so half a step beyond is fine.
            const double d = static_cast<double>(v);
            const double q = std::round((d - options.rescaleIntercept) / options.rescaleSlope);
            if (options.clampToStorage && std::isfinite(d)) continue;
            if (!(q >= 0.0 && q <= 65535.0)) {
                throw ValueError(name + ": expected values in [" + num(lo) + ", " + num(hi) +
                                 "] to fit uint16 storage with slope " + num(options.rescaleSlope) +
                                 " and intercept " + num(options.rescaleIntercept) + ", found " +
                                 num(d));
            }
        }
    }
}

/// Creates @p dir (noted in @p cleanup) or checks that it is an empty directory.
/// @throw IoError naming @p dir.
void prepareDirectory(const fs::path& dir, Cleanup& cleanup) {
    const std::string where = dir.string();
    std::error_code ec;
    if (fs::exists(dir, ec)) {
        if (!fs::is_directory(dir, ec))
            throw IoError(where + ": expected a directory, found a file");
        if (!fs::is_empty(dir, ec)) {
            throw IoError(
                where +
                ": expected a new or empty directory for the series, found existing entries");
        }
    } else {
        if (!fs::create_directories(dir, ec) || ec) {
            throw IoError(where + ": expected to create the directory, found " +
                          (ec ? ec.message() : std::string("it could not be created")));
        }
        cleanup.createdDir = dir;
    }
}

/// What every file of the series shares.
struct SeriesIds {
    std::string studyUid, seriesUid, frameUid;
    const char* sopClass = nullptr;
    std::string date, time;  // one study and series date/time for every file (DA, TM)
};

/// Writes @p writer's file as the classic image its SOP class says. GDCM writes an MR image with
/// a rescale (slope not 1 or intercept not 0) as an Enhanced MR image, its plane (Image Position,
/// Orientation, Pixel Spacing) inside functional groups, unless told to keep the classic
/// image's rescale (gdcmImageHelper.h, ForceRescaleInterceptSlope); the flag is process-wide,
/// so it is set for this write only and restored.
bool writeKeepingRescale(gdcm::ImageWriter& writer) {
    struct Force {
        const bool previous = gdcm::ImageHelper::GetForceRescaleInterceptSlope();
        Force() { gdcm::ImageHelper::SetForceRescaleInterceptSlope(true); }
        ~Force() { gdcm::ImageHelper::SetForceRescaleInterceptSlope(previous); }
        Force(const Force&) = delete;
        Force& operator=(const Force&) = delete;
    } force;
    return writer.Write();
}

/// Writes slice @p k of @p stack to @p finalPath through a temporary file; @p stored is scratch.
/// @throw IoError naming the file.
void writeSlice(const SliceStack& stack, std::size_t k, const DicomWriteOptions& options,
                const SeriesIds& ids, gdcm::UIDGenerator& gen, const fs::path& finalPath,
                std::vector<std::uint16_t>& stored, Cleanup& cleanup) {
    const Slice& s = stack.slices[k];
    const double colSpacing = s.colStep.norm();
    const double rowSpacing = s.rowStep.norm();
    const Eigen::Vector3d rowCosine = s.colStep / colSpacing;  // DICOM "row" direction
    const Eigen::Vector3d colCosine = s.rowStep / rowSpacing;
    const Eigen::Vector3d normal = rowCosine.cross(colCosine).normalized();
    double thickness = 0;
    if (stack.slices.size() > 1) {
        const Slice& other =
            k + 1 < stack.slices.size() ? stack.slices[k + 1] : stack.slices[k - 1];
        thickness = std::abs((other.position - s.position).dot(normal));
    }
    if (!(thickness > 0))
        thickness = stack.info.originalSpacing[2] > 0 ? stack.info.originalSpacing[2] : colSpacing;

    stored.resize(s.values.size());
    for (std::size_t i = 0; i < s.values.size(); ++i) {
        const double q = std::round((static_cast<double>(s.values[i]) - options.rescaleIntercept) /
                                    options.rescaleSlope);
        stored[i] = static_cast<std::uint16_t>(std::clamp(q, 0.0, 65535.0));
    }

    gdcm::ImageWriter writer;
    gdcm::Image& image = writer.GetImage();
    image.SetNumberOfDimensions(2);
    image.SetDimension(0, static_cast<unsigned int>(s.cols));
    image.SetDimension(1, static_cast<unsigned int>(s.rows));
    image.SetPixelFormat(gdcm::PixelFormat(gdcm::PixelFormat::UINT16));
    image.SetPhotometricInterpretation(gdcm::PhotometricInterpretation::MONOCHROME2);
    image.SetTransferSyntax(gdcm::TransferSyntax::ExplicitVRLittleEndian);
    image.SetSpacing(0, colSpacing * 1e3);
    image.SetSpacing(1, rowSpacing * 1e3);
    image.SetSpacing(2, thickness * 1e3);
    const Eigen::Vector3d originMm = s.position * 1e3;
    // Per component: the array overload copies only GetNumberOfDimensions() values.
    for (unsigned int a = 0; a < 3; ++a) image.SetOrigin(a, originMm[static_cast<Eigen::Index>(a)]);
    const double cosines[6] = {rowCosine.x(), rowCosine.y(), rowCosine.z(),
                               colCosine.x(), colCosine.y(), colCosine.z()};
    image.SetDirectionCosines(cosines);
    image.SetSlope(options.rescaleSlope);
    image.SetIntercept(options.rescaleIntercept);
    gdcm::DataElement pixels(gdcm::Tag(0x7fe0, 0x0010));
    pixels.SetByteValue(reinterpret_cast<const char*>(stored.data()),
                        static_cast<std::uint32_t>(stored.size() * sizeof(std::uint16_t)));
    image.SetDataElement(pixels);

    gdcm::File& file = writer.GetFile();
    file.GetHeader().SetDataSetTransferSyntax(gdcm::TransferSyntax::ExplicitVRLittleEndian);
    gdcm::DataSet& ds = file.GetDataSet();
    setString(ds, 0x0008, 0x0016, gdcm::VR::UI, ids.sopClass);
    setString(ds, 0x0008, 0x0018, gdcm::VR::UI, uid(gen));
    setString(ds, 0x0008, 0x0008, gdcm::VR::CS, "DERIVED\\SECONDARY\\AXIAL");
    setString(ds, 0x0008, 0x0060, gdcm::VR::CS, options.modality);
    setString(ds, 0x0028, 0x0004, gdcm::VR::CS, "MONOCHROME2");
    setString(ds, 0x0008, 0x103e, gdcm::VR::LO, options.seriesDescription.substr(0, 64));
    setString(ds, 0x0010, 0x0010, gdcm::VR::PN, "PALP^PHANTOM");
    setString(ds, 0x0010, 0x0020, gdcm::VR::LO, "PHANTOM");
    // Study and series date/time, the same in every file (gdcm would stamp each file with the
    // time it is written, and readers such as dcm2niix split a series whose study time varies).
    setString(ds, 0x0008, 0x0020, gdcm::VR::DA, ids.date);
    setString(ds, 0x0008, 0x0030, gdcm::VR::TM, ids.time);
    setString(ds, 0x0008, 0x0021, gdcm::VR::DA, ids.date);
    setString(ds, 0x0008, 0x0031, gdcm::VR::TM, ids.time);
    setString(ds, 0x0020, 0x000d, gdcm::VR::UI, ids.studyUid);
    setString(ds, 0x0020, 0x000e, gdcm::VR::UI, ids.seriesUid);
    setString(ds, 0x0020, 0x0052, gdcm::VR::UI, ids.frameUid);
    setString(ds, 0x0020, 0x0010, gdcm::VR::SH, "1");                    // StudyID
    setString(ds, 0x0020, 0x0011, gdcm::VR::IS, "1");                    // SeriesNumber
    setString(ds, 0x0020, 0x0013, gdcm::VR::IS, std::to_string(k + 1));  // InstanceNumber
    setString(ds, 0x0018, 0x0050, gdcm::VR::DS, num(thickness * 1e3).substr(0, 16));
    if (options.gantryTiltDeg != 0) {
        setString(ds, 0x0018, 0x1120, gdcm::VR::DS, num(options.gantryTiltDeg).substr(0, 16));
    }

    AtomicFile out(finalPath, "DICOM file");
    writer.SetFileName(out.tempPath().string().c_str());
    if (!writeKeepingRescale(writer))
        throw IoError(out.tempPath().string() +
                      ": expected to write a DICOM file, found a write failure");
    cleanup.paths.push_back(finalPath);
    out.commit();
}

}  // namespace

namespace dicom {

void writeSeries(const SliceStack& stack, const fs::path& dir, const DicomWriteOptions& options) {
    checkWritable(stack, options, dir.string());
    Cleanup cleanup;
    prepareDirectory(dir, cleanup);

    gdcm::UIDGenerator gen;
    SeriesIds ids;
    ids.studyUid = uid(gen);
    ids.seriesUid = uid(gen);
    ids.frameUid = uid(gen);
    {
        const std::time_t now = std::time(nullptr);
        std::tm utc{};
        gmtime_r(&now, &utc);
        char date[16], time[16];
        std::strftime(date, sizeof date, "%Y%m%d", &utc);
        std::strftime(time, sizeof time, "%H%M%S", &utc);
        ids.date = date;
        ids.time = time;
    }
    const bool isCt = options.modality == "CT";
    ids.sopClass = isCt ? gdcm::MediaStorage::GetMSString(gdcm::MediaStorage::CTImageStorage)
                        : gdcm::MediaStorage::GetMSString(gdcm::MediaStorage::MRImageStorage);
    const int digits = stack.slices.size() < 10000 ? 4 : 6;
    std::vector<std::uint16_t> stored;
    for (std::size_t k = 0; k < stack.slices.size(); ++k) {
        char name[32];
        std::snprintf(name, sizeof name, "IMG%0*zu.dcm", digits, k + 1);
        writeSlice(stack, k, options, ids, gen, dir / name, stored, cleanup);
    }
    cleanup.armed = false;
}

}  // namespace dicom
}  // namespace palp::volume
