// Parameters: CouplingParams, ProxyParams, WorkspaceTransform and SessionParams as Python
// classes with snake_case fields (the coupling's nested bundle / first-hit / accumulate settings
// flattened), keyword constructors, and the coupling defaults of scans and phantoms.
#include <pybind11/eigen.h>
#include <pybind11/stl.h>

#include <string>

#include "bindings.h"
#include "palp/base/error.h"
#include "palp/haptics/rendering/coupling_defaults.h"
#include "palp/haptics/session.h"
#include "palp/volume/phantom.h"

namespace palp::python {

using haptics::CouplingMode;
using haptics::CouplingParams;
using haptics::ProxyParams;
using haptics::RaySource;
using haptics::RecontactParams;
using haptics::SessionParams;
using haptics::WorkspaceTransform;

namespace {

CouplingMode parseMode(const std::string& name) {
    for (CouplingMode m : {CouplingMode::VC, CouplingMode::AVC, CouplingMode::AVCEC}) {
        if (name == haptics::couplingModeName(m)) return m;
    }
    throw ValueError("coupling mode: expected vc, avc or avcec, found '" + name + "'");
}

RaySource parseSource(const std::string& name) {
    for (RaySource s : {RaySource::Mesh, RaySource::VolumeFirstHit, RaySource::VolumeAccumulate}) {
        if (name == haptics::raySourceName(s)) return s;
    }
    throw ValueError("ray source: expected mesh, first-hit or accumulate, found '" + name + "'");
}

/// A read-write property for the member @p ptr of the nested struct @p outer.
template <class C, class Outer, class T>
void nested(py::class_<C>& cls, const char* name, Outer C::*outer, T Outer::*ptr, const char* doc) {
    cls.def_property(
        name, [outer, ptr](const C& c) { return c.*outer.*ptr; },
        [outer, ptr](C& c, T v) { c.*outer.*ptr = v; }, doc);
}

}  // namespace

void bindParams(py::module_& m) {
    py::class_<CouplingParams> coupling(
        m, "CouplingParams",
        "Virtual coupling settings (palp::haptics::CouplingParams): mode 'vc' | 'avc' | "
        "'avcec', ray source 'first-hit' | 'accumulate' | 'mesh'; SI units. Keyword "
        "constructor: CouplingParams(mode='vc', base_stiffness=300).");
    coupling.def(py::init(&fromKwargs<CouplingParams>))
        .def_property(
            "mode", [](const CouplingParams& c) { return haptics::couplingModeName(c.mode); },
            [](CouplingParams& c, const std::string& s) { c.mode = parseMode(s); })
        .def_property(
            "source", [](const CouplingParams& c) { return haptics::raySourceName(c.source); },
            [](CouplingParams& c, const std::string& s) { c.source = parseSource(s); })
        .def_readwrite("base_stiffness", &CouplingParams::baseStiffness, "k_s, N/m")
        .def_readwrite("reference_length", &CouplingParams::referenceLength, "L_ref, m")
        .def_readwrite("max_multiplier", &CouplingParams::maxMultiplier, "m_max")
        .def_readwrite("max_stiffness", &CouplingParams::maxStiffness, "k_max, N/m")
        .def_readwrite("damping", &CouplingParams::damping, "b, N s/m")
        .def_readwrite("min_distance", &CouplingParams::minDistance, "eps, m")
        .def_readwrite("stiffness_time_constant", &CouplingParams::stiffnessTimeConstant,
                       "tau, s: k low-passed over ticks on deformable tissue (0: none)")
        .def_readwrite("max_ray_tilt", &CouplingParams::maxRayTilt,
                       "theta_c, rad (AVCEC): the rays' largest tilt from the contact's inward "
                       "normal (pi/2: none)")
        .def_readwrite("hard_mask", &CouplingParams::hardMask, "mesh source targets (bits)");
    using kernels::AccumulateParams;
    using kernels::BundleParams;
    using kernels::FirstHitParams;
    nested(coupling, "ray_length", &CouplingParams::bundle, &BundleParams::length, "L_max, m");
    nested(coupling, "ring_count", &CouplingParams::bundle, &BundleParams::ringCount, "");
    nested(coupling, "ring_half_angle", &CouplingParams::bundle, &BundleParams::ringHalfAngle,
           "rad");
    nested(coupling, "ring_weight_sigma", &CouplingParams::bundle, &BundleParams::ringWeightSigma,
           "rad");
    nested(coupling, "sobel_angle", &CouplingParams::bundle, &BundleParams::sobelAngle,
           "delta, rad");
    nested(coupling, "surface_offset", &CouplingParams::bundle, &BundleParams::surfaceOffset,
           "h, m");
    nested(coupling, "first_hit_threshold", &CouplingParams::firstHit, &FirstHitParams::threshold,
           "value units (HU)");
    nested(coupling, "first_hit_step", &CouplingParams::firstHit, &FirstHitParams::step, "m");
    nested(coupling, "accumulate_tau_stop", &CouplingParams::accumulate, &AccumulateParams::tauStop,
           "");
    nested(coupling, "accumulate_step", &CouplingParams::accumulate, &AccumulateParams::step, "m");
    coupling.def("validate", &haptics::validateCouplingParams,
                 "Raises palp.ValueError naming the field.");

    py::class_<ProxyParams>(m, "ProxyParams", "God-object proxy settings (friction, epsilon).")
        .def(py::init(&fromKwargs<ProxyParams>))
        .def_readwrite("static_friction", &ProxyParams::staticFriction)
        .def_readwrite("dynamic_friction", &ProxyParams::dynamicFriction)
        .def_readwrite("epsilon", &ProxyParams::epsilon, "m")
        .def_readwrite("surface_mask", &ProxyParams::surfaceMask)
        .def_readwrite("max_iterations", &ProxyParams::maxIterations);

    py::class_<WorkspaceTransform>(m, "WorkspaceTransform",
                                   "Device frame -> world: offset + scale * rotation * device.")
        .def(py::init(&fromKwargs<WorkspaceTransform>))
        .def_readwrite("scale", &WorkspaceTransform::scale)
        .def_readwrite("rotation", &WorkspaceTransform::rotation)
        .def_readwrite("offset", &WorkspaceTransform::offset, "m");

    py::class_<RecontactParams>(m, "RecontactParams",
                                "Deformable tissue: the force's rise after the tissue springs "
                                "back past the probe (seconds: the window, 0 = off; rise_nps).")
        .def(py::init(&fromKwargs<RecontactParams>))
        .def_readwrite("seconds", &RecontactParams::seconds, "s")
        .def_readwrite("rise_nps", &RecontactParams::riseNps, "N/s");

    py::class_<SessionParams>(m, "SessionParams",
                              "Everything a Session is made with (coupling, proxy, workspace, "
                              "passivity control, start-up gate, servo period).")
        .def(py::init(&fromKwargs<SessionParams>))
        .def_readwrite("coupling", &SessionParams::coupling)
        .def_readwrite("proxy", &SessionParams::proxy)
        .def_readwrite("workspace", &SessionParams::workspace)
        .def_readwrite("passivity_control", &SessionParams::passivityControl)
        .def_readwrite("startup_threshold", &SessionParams::startupThresholdN, "N")
        .def_readwrite("startup_quiet_ticks", &SessionParams::startupQuietTicks)
        .def_readwrite("cross_fade_seconds", &SessionParams::crossFadeSeconds)
        .def_readwrite("recontact", &SessionParams::recontact)
        .def_property(
            "period", [](const SessionParams& p) { return p.servo.periodSeconds; },
            [](SessionParams& p, double s) { p.servo.periodSeconds = s; }, "servo period T, s")
        .def("validate", &haptics::validateSessionParams);

    m.def("scan_coupling_defaults", &haptics::scanCouplingDefaults,
          "Coupling defaults for a CT scan: AVC, first hit at 300 HU, L_max = L_ref = 40 mm.");
    m.def(
        "scene_coupling_defaults",
        [](const std::string& scene) {
            return haptics::sceneCouplingDefaults(volume::parseScene(scene));
        },
        py::arg("scene"), "Coupling defaults for a phantom scene (avc, avcec, bone, ...).");
}

}  // namespace palp::python
