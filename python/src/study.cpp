// Perception studies for a viewer (palp.Study): a StudySession one trial at a time, each interval
// rendered on the viewer's device by a palp.Session built from its scene and parameters.
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cmath>
#include <optional>
#include <string>

#include "bindings.h"
#include "palp/base/error.h"
#include "palp/studies/study_session.h"
#include "palp/studies/study_spec.h"

namespace palp::python {

namespace {

using haptics::StudySession;

std::unique_ptr<StudySession> openStudy(const std::filesystem::path& study,
                                        std::optional<std::filesystem::path> log,
                                        std::optional<std::filesystem::path> resume,
                                        std::optional<int> participant) {
    if (log.has_value() == resume.has_value())
        throw ValueError(
            "palp.Study: expected one of log= (a new log) or resume= (a log to "
            "continue), found " +
            std::string(log ? "both" : "neither"));
    haptics::StudySpec spec = haptics::loadStudySpec(study);
    if (log) {
        const int p = participant.value_or(0);
        if (p < 0)
            throw ValueError("palp.Study: participant: expected >= 0, found " + std::to_string(p));
        return std::make_unique<StudySession>(StudySession::create(std::move(spec), *log, p));
    }
    return std::make_unique<StudySession>(
        StudySession::resume(std::move(spec), *resume, participant.value_or(-1)));
}

py::dict trialDict(const StudySession& s) {
    const haptics::TrialPlan p = s.next();
    py::dict d;
    d["trial"] = p.trial;
    d["condition"] = p.condition;
    d["condition_name"] = s.spec().conditions[static_cast<std::size_t>(p.condition)].name;
    d["condition_trial"] = p.conditionTrial;
    d["level_percent"] = p.levelPercent;
    d["comparison_interval"] = p.comparisonInterval;
    d["interval_stiffness"] = py::make_tuple(s.intervalParams(1).coupling.baseStiffness,
                                             s.intervalParams(2).coupling.baseStiffness);
    return d;
}

py::object number(double v) { return std::isfinite(v) ? py::float_(v) : py::object(py::none()); }

py::list resultsList(const StudySession& s) {
    py::list out;
    for (const haptics::ConditionResult& r : s.results()) {
        py::dict d;
        d["name"] = r.name;
        d["trials"] = r.trials;
        d["reversals"] = r.reversals;
        d["target"] = r.target;
        d["jnd_procedure_percent"] = number(r.procedureThreshold);
        d["jnd_fit_percent"] = number(r.fitThreshold);
        d["jnd_fit_interval_percent"] =
            py::make_tuple(number(r.fitInterval.lo), number(r.fitInterval.hi));
        if (!r.note.empty()) d["note"] = r.note;
        out.append(d);
    }
    return out;
}

}  // namespace

void bindStudy(py::module_& m) {
    py::class_<StudySession>(
        m, "Study",
        "A two-interval stiffness study run one trial at a time by a viewer (docs/studies.md): "
        "next() gives the trial; for each interval build palp.Session(study.scene(), device, "
        "study.interval_params(i), spec=study.device) on the person's device and let them "
        "touch it (lift the stylus between intervals: the proxy starts at the probe); answer() "
        "logs the interval they named stiffer, synced before the next trial. "
        "Study(file, log=NEW) starts a log (an existing file is refused); Study(file, "
        "resume=LOG) continues one with the sequence an uninterrupted run would have given.")
        .def(py::init(&openStudy), py::arg("study"), py::kw_only(), py::arg("log") = py::none(),
             py::arg("resume") = py::none(), py::arg("participant") = py::none())
        .def_property_readonly("finished", &StudySession::finished)
        .def_property_readonly("device", [](const StudySession& s) { return s.spec().device; })
        .def_property_readonly("log_path", &StudySession::logPath)
        .def_property_readonly("participant",
                               [](const StudySession& s) { return s.runner().participant(); })
        .def("next", &trialDict,
             "The trial to present: a dict of trial, condition, condition_name, condition_trial, "
             "level_percent, comparison_interval (never shown to the participant) and "
             "interval_stiffness (k_s of intervals 1 and 2, N/m). palp.ValueError once finished.")
        .def(
            "scene",
            [](StudySession& s) { return std::const_pointer_cast<haptics::Scene>(s.scene()); },
            "The phantom of the next trial's condition (shared; do not change it).")
        .def("interval_params", &StudySession::intervalParams, py::arg("interval"),
             "SessionParams of interval 1 or 2 of the next trial: its coupling (the "
             "stiffness field at its level), the study's friction, 1 kHz.")
        .def(
            "answer",
            [](StudySession& s, int response, double seconds, const std::string& trace) {
                haptics::TrialAnswer a;
                a.response = response;
                a.responseSeconds = seconds;
                a.trace = trace;
                s.answer(a);
            },
            py::arg("response"), py::arg("response_seconds") = 0.0, py::arg("trace") = "",
            "Logs the interval the person named stiffer (1 or 2) for the next trial.")
        .def("results", &resultsList,
             "Per condition: trials, reversals, the procedure's JND and the fit's JND with its "
             "bootstrap interval, percent (None where missing).");
}

}  // namespace palp::python
