// The one symbol libpalp_volume_dicom.so exports to palp_volume (dicom_plugin.h): the table of
// the DICOM room's entry points.
#include "dicom/dicom_scan.h"
#include "dicom/dicom_series.h"
#include "dicom_plugin.h"

extern "C" __attribute__((visibility("default"))) const palp::volume::detail::DicomPlugin*
palp_volume_dicom_plugin() {
    namespace dicom = palp::volume::dicom;
    static const palp::volume::detail::DicomPlugin plugin{&dicom::scanSeries, &dicom::readSeries,
                                                          &dicom::openSeries, &dicom::writeSeries,
                                                          &dicom::findScans};
    return &plugin;
}
