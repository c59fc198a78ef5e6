// Scenes and sessions: palp.Scene (from a volume; deformable), palp.Snapshot, palp.Session
// (simulated, playback or Python devices; step(), run(n) as numpy columns, run-time parameter
// changes; start()/stop() for palp's own devices only).
#include "palp/haptics/session.h"

#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <array>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "bindings.h"
#include "palp/base/error.h"
#include "palp/haptics/devices/skin_patch.h"
#include "palp/haptics/devices/watchdog_device.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/haptics/tissue/error_control.h"
#include "palp/kernels/ray_bundle.h"
#include "palp/studies/offline_run.h"
#include "python_device.h"

namespace palp::python {

using haptics::Command;
using haptics::Device;
using haptics::Scene;
using haptics::Snapshot;

namespace {

fem::BoxFace parseFace(const std::string& name) {
    static const std::pair<const char*, fem::BoxFace> kFaces[] = {
        {"x_min", fem::BoxFace::xMin}, {"x_max", fem::BoxFace::xMax},
        {"y_min", fem::BoxFace::yMin}, {"y_max", fem::BoxFace::yMax},
        {"z_min", fem::BoxFace::zMin}, {"z_max", fem::BoxFace::zMax}};
    for (const auto& [n, f] : kFaces) {
        if (name == n) return f;
    }
    throw ValueError("support_face: expected x_min, x_max, y_min, y_max, z_min or z_max, found '" +
                     name + "'");
}

/// A session and what it refers to (the scene, the device and, for a Python device, its
/// wrapper), destroyed session first.
struct PySession {
    std::shared_ptr<Scene> scene;
    py::object deviceObject;               // keeps a Python or palp device alive
    std::unique_ptr<PythonDevice> python;  // a Python object's device, or null
    std::unique_ptr<haptics::WatchdogDevice> watchdog;
    haptics::CouplingParams coupling;  // the latest sent (set_params fills what it is not given)
    haptics::ProxyParams proxy;
    bool passivityControl = false;
    std::unique_ptr<haptics::Session> session;

    haptics::Session& s() { return *session; }
    void check() {
        if (python && python->pending()) python->rethrow();
    }
};

std::unique_ptr<PySession> makeSession(std::shared_ptr<Scene> scene, py::object device,
                                       std::optional<haptics::SessionParams> params,
                                       const std::string& spec, bool watchdog, int servoCpu,
                                       int servoPriority, bool servoReserveCpu) {
    if (!scene) throw ValueError("scene: expected a palp.Scene, found None");
    auto p = std::make_unique<PySession>();
    p->scene = std::move(scene);
    p->deviceObject = device;
    haptics::SessionParams sp = params.value_or(haptics::SessionParams{});
    sp.servo.cpu = servoCpu;  // checked by Session (validateServoConfig), naming the field
    sp.servo.priority = servoPriority;
    sp.servo.reserveCpu = servoReserveCpu;
    Device* inner = nullptr;
    if (py::isinstance<Device>(device)) {
        inner = device.cast<Device*>();
    } else {
        p->python = std::make_unique<PythonDevice>(device, deviceSpecByName(spec));
        inner = p->python.get();
    }
    if (watchdog) {
        p->watchdog = std::make_unique<haptics::WatchdogDevice>(*inner, haptics::WatchdogParams{},
                                                                sp.servo.periodSeconds);
        inner = p->watchdog.get();
    }
    if (p->python) {
        p->session = std::make_unique<haptics::Session>(p->scene, *inner, sp);
    } else {
        py::gil_scoped_release release;  // a deformable body is built here
        p->session = std::make_unique<haptics::Session>(p->scene, *inner, sp);
    }
    p->coupling = p->session->params().coupling;
    p->proxy = p->session->params().proxy;
    p->passivityControl = p->session->params().passivityControl;
    return p;
}

/// Snapshots as columns: (n,) arrays of scalars, (n, 3) arrays of vectors.
py::dict traceColumns(const std::vector<Snapshot>& trace) {
    const auto n = static_cast<py::ssize_t>(trace.size());
    py::dict d;
    auto vec = [&](const char* name, Eigen::Vector3d Snapshot::*member) {
        py::array_t<double> a(std::vector<py::ssize_t>{n, 3});
        auto r = a.mutable_unchecked<2>();
        for (py::ssize_t i = 0; i < n; ++i)
            for (py::ssize_t c = 0; c < 3; ++c) r(i, c) = (trace[std::size_t(i)].*member)(c);
        d[name] = a;
    };
    auto col = [&](const char* name, auto member) {
        using T = std::remove_cvref_t<decltype(trace[0].*member)>;
        using Out = std::conditional_t<std::is_same_v<T, unsigned>, std::uint32_t, T>;
        py::array_t<Out> a(n);
        auto r = a.template mutable_unchecked<1>();
        for (py::ssize_t i = 0; i < n; ++i) r(i) = static_cast<Out>(trace[std::size_t(i)].*member);
        d[name] = a;
    };
    col("tick", &Snapshot::tick);
    col("time", &Snapshot::timeSeconds);
    vec("probe", &Snapshot::probe);
    vec("proxy", &Snapshot::proxy);
    vec("force", &Snapshot::force);
    vec("coupling_force", &Snapshot::couplingForce);
    vec("energy_force", &Snapshot::energyForce);
    vec("proxy_force", &Snapshot::proxyForce);
    vec("tissue_force", &Snapshot::tissueForce);
    col("stiffness", &Snapshot::stiffness);
    col("ray_length", &Snapshot::rayLength);
    col("distance", &Snapshot::distance);
    col("coupling_energy", &Snapshot::couplingEnergy);
    col("observer_energy", &Snapshot::observerEnergy);
    col("added_damping", &Snapshot::addedDamping);
    col("passivity_cut", &Snapshot::passivityCut);
    col("contact_count", &Snapshot::contactCount);
    col("rays", &Snapshot::rays);
    col("sticking", &Snapshot::sticking);
    col("gate_open", &Snapshot::gateOpen);
    col("faulted", &Snapshot::faulted);
    col("clamped", &Snapshot::clamped);
    col("stiffness_limited", &Snapshot::stiffnessLimited);
    col("fading", &Snapshot::fading);
    col("fade_weight", &Snapshot::fadeWeight);
    col("device_stale", &Snapshot::deviceStale);
    col("device_force_scale", &Snapshot::deviceForceScale);
    col("fault_flags", &Snapshot::faultFlags);
    col("max_displacement", &Snapshot::maxDisplacement);
    col("contact_node", &Snapshot::contactNode);
    py::array_t<std::uint8_t> mode(n);
    auto r = mode.mutable_unchecked<1>();
    for (py::ssize_t i = 0; i < n; ++i)
        r(i) = static_cast<std::uint8_t>(trace[std::size_t(i)].mode);
    d["mode"] = mode;  // 0 vc, 1 avc, 2 avcec
    return d;
}

py::dict run(PySession& p, std::uint64_t ticks, std::uint64_t every) {
    if (every == 0) throw ValueError("run: every: expected at least 1, found 0");
    std::vector<Snapshot> trace;
    if (p.python) {  // Python device: each tick calls into Python, with the GIL held
        trace.reserve(static_cast<std::size_t>(ticks / every + 1));
        for (std::uint64_t i = 0; i < ticks; ++i) {
            const Snapshot& s = p.s().step();
            p.check();
            if ((i + 1) % every == 0 || i + 1 == ticks) trace.push_back(s);
        }
    } else {
        py::gil_scoped_release release;
        trace = haptics::runOffline(p.s(), ticks, every);
    }
    return traceColumns(trace);
}

/// A ray bundle's rays as numpy (for drawing): 'origins', 'directions' (n, 3), 'lengths',
/// 'weights' (n,) and the slices 'ring', 'sphere', 'surface' (row 0 is the centre ray).
py::dict bundleColumns(const kernels::RayBundle& b) {
    const auto n = static_cast<py::ssize_t>(b.count);
    py::array_t<double> o(std::vector<py::ssize_t>{n, 3});
    py::array_t<double> d(std::vector<py::ssize_t>{n, 3});
    py::array_t<double> length(n), weight(n);
    auto ro = o.mutable_unchecked<2>();
    auto rd = d.mutable_unchecked<2>();
    for (py::ssize_t i = 0; i < n; ++i) {
        const auto r = static_cast<std::size_t>(i);
        ro(i, 0) = b.ox[r], ro(i, 1) = b.oy[r], ro(i, 2) = b.oz[r];
        rd(i, 0) = b.dx[r], rd(i, 1) = b.dy[r], rd(i, 2) = b.dz[r];
        length.mutable_at(i) = b.length[r];
        weight.mutable_at(i) = b.weight[r];
    }
    py::dict out;
    out["origins"] = o;
    out["directions"] = d;
    out["lengths"] = length;
    out["weights"] = weight;
    out["ring"] = py::slice(b.ringBegin, b.ringBegin + b.ringCount, 1);
    out["sphere"] = py::slice(b.sphereBegin, b.sphereBegin + 8, 1);
    out["surface"] = py::slice(b.surfaceBegin, b.surfaceBegin + 8, 1);
    return out;
}

bool send(PySession& p, const Command& c) {
    return p.s().send(c);  // validated here; false: the queue is full
}

}  // namespace

void bindSession(py::module_& m) {
    py::class_<Scene, std::shared_ptr<Scene>>(
        m, "Scene", "What a session feels: a volume, its iso-surfaces, optionally deformable.")
        .def_static(
            "from_volume",
            [](const volume::Volume& v, double surfaceIso, std::optional<double> hardIso,
               double adaptivity) {
                haptics::SceneOptions o;
                o.surfaceIso = surfaceIso;
                o.hardIso = hardIso.value_or(std::nan(""));
                o.adaptivity = adaptivity;
                py::gil_scoped_release release;
                return haptics::Scene::fromVolume(v, o);
            },
            py::arg("volume"), py::kw_only(), py::arg("surface_iso") = -500.0,
            py::arg("hard_iso") = py::none(), py::arg("adaptivity") = 0.0,
            "The skin at surface_iso (proxy surface) and, with hard_iso, hard meshes for the "
            "mesh ray source; values in the volume's units (HU).")
        .def(
            "make_deformable",
            [](Scene& scene, const volume::Volume& v, double elementSize, double tissue,
               double bone, double youngs, double poisson, double alpha,
               std::optional<std::string> supportFace, double period, bool dropInsideBone,
               const std::string& solver, std::optional<Eigen::Vector3d> regionsCentre,
               std::optional<haptics::SkinPatch> slidePatch, const std::string& material,
               std::optional<std::string> materialTable) {
                haptics::DeformableSetup s;
                if (solver != "auto" && solver != "explicit" && solver != "regions")
                    throw ValueError(
                        "make_deformable solver: expected 'auto', 'explicit' or "
                        "'regions', found '" +
                        solver + "'");
                if (material != "linear" && material != "neo-hookean")
                    throw ValueError(
                        "make_deformable material: expected 'linear' or 'neo-hookean', found '" +
                        material + "'");
                if (material == "neo-hookean") s.material.law = fem::MaterialLaw::neoHookean;
                if (materialTable) {
                    try {
                        s.materialTable = haptics::MaterialTable::named(*materialTable);
                    } catch (const Error& e) {
                        throw ValueError("make_deformable material_table: " +
                                         std::string(e.what()));
                    }
                }
                s.autoSolver = solver == "auto";
                if (solver == "regions")
                    s.options.solverKind = haptics::DeformableSolver::asyncRegions;
                s.options.regions.lod = 0;  // the lattice decides
                s.voxelize.elementSize = elementSize;
                s.voxelize.tissueThreshold = tissue;
                s.voxelize.boneThreshold = bone;
                s.voxelize.insideBone =
                    dropInsideBone ? fem::InsideBone::drop : fem::InsideBone::keep;
                s.material.youngsModulus = youngs;
                s.material.poissonRatio = poisson;
                s.material.dampingAlpha = alpha;
                if (supportFace) s.supportFace = parseFace(*supportFace);
                s.setPeriod(period);
                if (regionsCentre) s.options.regionsCentre = *regionsCentre;
                if (slidePatch) {
                    s.slidePatch = haptics::SlidePatch{slidePatch->centre,  slidePatch->u,
                                                       slidePatch->v,       slidePatch->press,
                                                       slidePatch->extentU, slidePatch->extentV};
                }
                haptics::SolverChoice choice;
                {
                    py::gil_scoped_release release;
                    auto model = haptics::makeDeformableModel(v, s, &choice);
                    choice.solver = model->options().solverKind;
                    s.options.regions.lod = model->options().regions.lod;
                    scene.setDeformable(std::move(model));
                }
                const bool regions = choice.solver == haptics::DeformableSolver::asyncRegions;
                py::dict out;
                out["solver"] = regions ? "regions" : "explicit";
                out["chosen"] = s.autoSolver;
                out["element_substeps"] = choice.elementSubsteps;
                out["budget"] = choice.budget;
                out["lod"] = regions ? s.options.regions.lod : 0;
                out["reason"] = choice.reason;
                return out;
            },
            py::arg("volume"), py::kw_only(), py::arg("element_size") = 5e-3,
            py::arg("tissue_threshold") = -200.0, py::arg("bone_threshold") = 500.0,
            py::arg("youngs_modulus") = 5e3, py::arg("poisson_ratio") = 0.45,
            py::arg("damping_alpha") = 60.0, py::arg("support_face") = py::none(),
            py::arg("period") = 1e-3, py::arg("drop_inside_bone") = true,
            py::arg("solver") = "auto", py::arg("regions_centre") = py::none(),
            py::arg("slide_patch") = py::none(), py::arg("material") = "linear",
            py::arg("material_table") = py::none(),
            "Makes the scene deformable (palp palpate --deformable's body): sessions made "
            "afterwards build their own FEM body from it. bone_threshold inf: no bone. solver: "
            "'auto' (the whole mesh where it makes the 1 kHz tick, else the asynchronous "
            "regions, threaded: a patient's CT), 'explicit' or 'regions'. With the regions: "
            "regions_centre (m; the free surface node nearest it starts the primary region: "
            "where the hand will press) and slide_patch (a SkinPatch, find_skin_patch(): the "
            "skin under it is what the contact slides over without a factorisation per move, "
            "as palp palpate lays it under its path on a scan). material: 'linear' or "
            "'neo-hookean' (large strain, TLED: on the whole mesh, or in the regions' primary with "
            "a linear far field). "
            "material_table: 'ct' (the table palp ships) or a CSV file giving each element's "
            "modulus from the volume's value, and nu and density, in place of youngs_modulus "
            "and poisson_ratio (docs/algorithms.md 5.2). Returns the solver "
            "that runs and why: {'solver': 'explicit'|'regions', 'chosen': auto chose it, "
            "'element_substeps', 'budget' (auto only), 'lod', 'reason'}.")
        .def(
            "error_estimate",
            [](const Scene& scene, std::optional<double> strain, std::optional<double> frequency) {
                if (!scene.deformable())
                    throw ValueError(
                        "error_estimate: expected a deformable scene, found a rigid one");
                const double nan = std::numeric_limits<double>::quiet_NaN();
                const haptics::ErrorEstimate e = haptics::estimateBodyError(
                    *scene.deformable(), strain.value_or(nan), frequency.value_or(nan));
                py::dict out;
                out["percent"] = e.percent;
                out["in_range"] = e.inRange();
                return out;
            },
            py::kw_only(), py::arg("strain") = py::none(), py::arg("frequency") = py::none(),
            "The contact-force error (percent) palp's error table predicts for the deformable "
            "body's regions at an input of strain (contact displacement amplitude / the body's "
            "thickness along the press) and frequency (Hz); None: the worst the table holds "
            "over it. 0 on the whole mesh. {'percent', 'in_range' (no coordinate clamped to the "
            "sweep's ranges)} (docs/error_analysis.md).")
        .def("make_rigid", [](Scene& s) { s.setDeformable(nullptr); })
        .def_property_readonly("deformable",
                               [](const Scene& s) { return s.deformable() != nullptr; })
        .def_property_readonly("surface_triangle_count",
                               [](const Scene& s) { return s.surfaces().triangleCount(); });

    py::class_<Snapshot>(m, "Snapshot", "One tick's state (world frame, SI units).")
        .def_readonly("tick", &Snapshot::tick)
        .def_readonly("time", &Snapshot::timeSeconds)
        .def_readonly("probe", &Snapshot::probe)
        .def_readonly("proxy", &Snapshot::proxy)
        .def_readonly("force", &Snapshot::force)
        .def_readonly("coupling_force", &Snapshot::couplingForce)
        .def_readonly("energy_force", &Snapshot::energyForce)
        .def_readonly("proxy_force", &Snapshot::proxyForce)
        .def_readonly("tissue_force", &Snapshot::tissueForce)
        .def_readonly("stiffness", &Snapshot::stiffness)
        .def_readonly("ray_length", &Snapshot::rayLength)
        .def_readonly("distance", &Snapshot::distance)
        .def_readonly("coupling_energy", &Snapshot::couplingEnergy)
        .def_readonly("observer_energy", &Snapshot::observerEnergy)
        .def_readonly("added_damping", &Snapshot::addedDamping)
        .def_readonly("passivity_cut", &Snapshot::passivityCut)
        .def_readonly("contact_count", &Snapshot::contactCount)
        .def_readonly("rays", &Snapshot::rays)
        .def_readonly("sticking", &Snapshot::sticking)
        .def_readonly("gate_open", &Snapshot::gateOpen)
        .def_readonly("faulted", &Snapshot::faulted)
        .def_readonly("clamped", &Snapshot::clamped)
        .def_property_readonly("mode",
                               [](const Snapshot& s) { return haptics::couplingModeName(s.mode); })
        .def_readonly("stiffness_limited", &Snapshot::stiffnessLimited)
        .def_readonly("fading", &Snapshot::fading)
        .def_readonly("fade_weight", &Snapshot::fadeWeight)
        .def_readonly("faults", &Snapshot::faults)
        .def_readonly("device_stale", &Snapshot::deviceStale)
        .def_readonly("device_force_scale", &Snapshot::deviceForceScale)
        .def_readonly("watchdog_trips", &Snapshot::watchdogTrips)
        .def_readonly("fault_flags", &Snapshot::faultFlags,
                      "This tick's fault bits (1 stale, 2 non-finite, 4 out of range, 8 too fast, "
                      "16 non-finite force, 32 force jump, 64 overload, 128 shed)")
        .def_property_readonly(
            "fault_counts",
            [](const Snapshot& s) {
                const haptics::FaultCounts& c = s.faultCounts;
                py::dict d;
                d["stale"] = c.stale;
                d["non_finite"] = c.nonFinite;
                d["out_of_range"] = c.outOfRange;
                d["too_fast"] = c.tooFast;
                d["force_non_finite"] = c.forceNonFinite;
                d["force_jump"] = c.forceJump;
                d["overload"] = c.overload;
                d["shed"] = c.shed;
                return d;
            },
            "Ticks so far with each fault, as a dict")
        .def_readonly("fault_trips", &Snapshot::faultTrips)
        .def_readonly("contact_node", &Snapshot::contactNode)
        .def_readonly("max_displacement", &Snapshot::maxDisplacement)
        .def("__repr__", [](const Snapshot& s) {
            return "<palp.Snapshot tick " + std::to_string(s.tick) + ", |F| " +
                   std::to_string(s.force.norm()) + " N, k " + std::to_string(s.stiffness) + ">";
        });

    py::class_<PySession>(
        m, "Session",
        "A haptic session on a scene with a device: a palp device (SimulatedDevice, "
        "PlaybackDevice) or any Python object with read() -> (position, velocity[, buttons[, "
        "timestamp[, sequence]]]) and write(force). Step it offline with step() / run(n); "
        "start() runs palp's own devices on the 1 kHz servo thread (never a Python device: the "
        "servo thread must not call into Python), pinned to servo_cpu (-1: the last CPU) at "
        "SCHED_FIFO servo_priority (0: normal priority), the process's other threads kept off its "
        "CPU while it runs unless servo_reserve_cpu=False; a SCHED_FIFO loop that misses more than "
        "half its deadlines in two windows of 0.4 s drops the priority and renders no force "
        "(stats()['overloaded']).")
        .def(py::init(&makeSession), py::arg("scene"), py::arg("device"),
             py::arg("params") = py::none(), py::kw_only(), py::arg("spec") = "3D Systems Touch",
             py::arg("watchdog") = false, py::arg("servo_cpu") = -1, py::arg("servo_priority") = 80,
             py::arg("servo_reserve_cpu") = true)
        .def(
            "step",
            [](PySession& p) {
                const Snapshot s = p.s().step();
                p.check();
                return s;
            },
            "One tick on this thread; returns its Snapshot.")
        .def("run", &run, py::arg("ticks"), py::arg("every") = 1,
             "Steps ticks times (GIL released for palp's devices) and returns every every-th "
             "snapshot (and the last) as a dict of numpy arrays: 'time' (n,), 'force' (n, 3), "
             "...")
        .def(
            "start",
            [](PySession& p) {
                if (p.python) {
                    throw ValueError(
                        "Session.start: a Python device cannot run on the 1 kHz "
                        "servo thread (it must not call into Python); step it "
                        "offline with step() or run()");
                }
                p.s().start();
            },
            "Runs on the servo thread (palp's own devices only).")
        .def("stop", [](PySession& p) { p.s().stop(); })
        .def_property_readonly("running", [](PySession& p) { return p.s().running(); })
        .def(
            "stats",
            [](PySession& p) {
                const haptics::ServoStats st = p.s().stats();
                py::dict d;
                d["ticks"] = st.ticks;
                d["misses"] = st.misses;
                d["skipped"] = st.skipped;
                d["compute_p99"] = st.compute.p99;
                d["overloaded"] = st.overloaded;
                d["fifo_dropped"] = st.fifoDropped;
                d["overloaded_at"] = st.overloadedAtSeconds;
                d["shedding"] = st.shedding;
                d["sheds"] = st.sheds;
                d["restores"] = st.restores;
                d["shed_at"] = st.shedAtSeconds;
                d["realtime"] = p.s().realtime().message;
                return d;
            },
            "The servo loop's figures as a dict: ticks, misses, skipped, compute_p99 (s), "
            "overloaded (the overrun budget was exceeded: SCHED_FIFO dropped, fifo_dropped, and "
            "no force rendered from overloaded_at s on), shedding / sheds / restores / shed_at "
            "(after one window over the budget the session shed work: VC in place of AVC/AVCEC, "
            "tissue frozen; restored after 10 s of calm), realtime (what the OS granted).")
        .def(
            "latest", [](PySession& p) { return Snapshot(p.s().latest()); },
            "The newest published snapshot (viewer thread).")
        .def(
            "set_coupling",
            [](PySession& p, const haptics::CouplingParams& c) {
                Command cmd;
                cmd.kind = Command::Kind::SetCoupling;
                cmd.coupling = c;
                const bool queued = send(p, cmd);
                if (queued) p.coupling = c;
                return queued;
            },
            py::arg("coupling"),
            "Queues a coupling change (cross-faded); False when the queue is full. Raises "
            "palp.ValueError for invalid parameters.")
        .def(
            "set_proxy",
            [](PySession& p, const haptics::ProxyParams& c) {
                Command cmd;
                cmd.kind = Command::Kind::SetProxy;
                cmd.proxy = c;
                const bool queued = send(p, cmd);
                if (queued) p.proxy = c;
                return queued;
            },
            py::arg("proxy"))
        .def(
            "set_passivity_control",
            [](PySession& p, bool on) {
                Command cmd;
                cmd.kind = Command::Kind::SetPassivityControl;
                cmd.flag = on;
                const bool queued = send(p, cmd);
                if (queued) p.passivityControl = on;
                return queued;
            },
            py::arg("on"))
        .def("reset_observer",
             [](PySession& p) {
                 Command cmd;
                 cmd.kind = Command::Kind::ResetObserver;
                 return send(p, cmd);
             })
        .def(
            "set_params",
            [](PySession& p, std::optional<haptics::CouplingParams> coupling,
               std::optional<haptics::ProxyParams> proxy, std::optional<bool> passivity,
               std::optional<std::string> mode) {
                Command cmd;
                cmd.kind = Command::Kind::SetAll;
                cmd.coupling = coupling.value_or(p.coupling);
                if (mode) {
                    haptics::CouplingParams& c = cmd.coupling;
                    py::cast(&c, py::return_value_policy::reference).attr("mode") = *mode;
                }
                cmd.proxy = proxy.value_or(p.proxy);
                cmd.flag = passivity.value_or(p.passivityControl);
                const bool queued = send(p, cmd);
                if (queued) {
                    p.coupling = cmd.coupling;
                    p.proxy = cmd.proxy;
                    p.passivityControl = cmd.flag;
                }
                return queued;
            },
            py::kw_only(), py::arg("coupling") = py::none(), py::arg("proxy") = py::none(),
            py::arg("passivity_control") = py::none(), py::arg("mode") = py::none(),
            "Changes coupling, proxy and the passivity controller at one tick boundary; what "
            "is not given keeps its last value; mode ('vc', 'avc', 'avcec') replaces the "
            "coupling's mode.")
        .def_property_readonly("params",
                               [](PySession& p) { return haptics::SessionParams(p.s().params()); })
        .def_property_readonly("stiffness_limited",
                               [](PySession& p) { return p.s().stiffnessLimited(); })
        .def_property_readonly(
            "device_spec", [](PySession& p) { return &p.s().deviceSpec(); },
            py::return_value_policy::reference)
        .def(
            "surface",
            [](PySession& p) -> py::object {
                const haptics::SurfaceFrame* f = p.s().latestSurface();
                if (!f || !p.scene->deformable()) return py::none();
                const auto nv = static_cast<py::ssize_t>(f->positions.size() / 3);
                py::array_t<float> v(std::vector<py::ssize_t>{nv, 3});
                std::copy(f->positions.begin(), f->positions.end(), v.mutable_data());
                const auto& tris = p.scene->deformable()->surface().triangles;
                const auto nt = static_cast<py::ssize_t>(tris.size());
                py::array_t<std::uint32_t> t(std::vector<py::ssize_t>{nt, 3});
                auto r = t.mutable_unchecked<2>();
                for (py::ssize_t i = 0; i < nt; ++i)
                    for (py::ssize_t c = 0; c < 3; ++c)
                        r(i, c) = tris[std::size_t(i)][std::size_t(c)];
                return py::make_tuple(v, t);
            },
            "Deformable scenes: (vertices (n, 3) float32 m, triangles (m, 3)) of the newest "
            "tick; None on a rigid scene.")
        .def(
            "rays", [](PySession& p) { return bundleColumns(p.s().latestRays()); },
            "The newest tick's ray bundle (viewer thread, like latest()): dict of 'origins' and "
            "'directions' (n, 3), 'lengths' (n,) L_max, 'weights' (n,) and the slices 'ring', "
            "'sphere', 'surface'; n = 0 in VC or without contact distance. The snapshot's "
            "rays counts those its tick traced (AVC: the centre and the ring), ray_length the "
            "centre ray's measured L.");

    m.def(
        "ray_bundle",
        // std::array, not Eigen, arguments: GCC 12 warns maybe-uninitialized inside
        // pybind11's Eigen caster here.
        [](const std::array<double, 3>& origin, const std::array<double, 3>& direction,
           const haptics::CouplingParams& params, const std::array<double, 3>& tangent1,
           const std::array<double, 3>& tangent2) -> py::object {
            kernels::validateBundleParams(params.bundle);
            using V = Eigen::Vector3d;
            kernels::RayBundle b;
            if (!kernels::generateBundle(V(origin.data()), V(direction.data()), V(tangent1.data()),
                                         V(tangent2.data()), params.bundle, b)) {
                return py::none();
            }
            return bundleColumns(b);
        },
        py::arg("origin"), py::arg("direction"), py::arg("coupling"), py::kw_only(),
        py::arg("tangent1") = std::array<double, 3>{},
        py::arg("tangent2") = std::array<double, 3>{},
        "The AVC/AVCEC ray bundle a coupling casts from origin (the proxy) along direction "
        "(probe - proxy), as Session.rays() gives it, for rays not published (a trace from "
        "run()). The surface stencil spans tangent1, tangent2 (the proxy's tangent plane; zero: "
        "the bundle's own e1, e2). None for a zero or non-finite direction. Pure; any thread.");
}

}  // namespace palp::python
