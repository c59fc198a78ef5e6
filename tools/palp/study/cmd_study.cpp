// palp study: a two-interval forced-choice stiffness study (docs/studies.md) run on a simulated
// observer that palpates the stiffness phantom, or on a person answering at the terminal;
// logged trial by trial, resumable, analysed by reversals and by a psychometric fit, plotted.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "../commands.h"
#include "../option_checks.h"
#include "../palpate_options.h"
#include "palp/base/error.h"
#include "palp/haptics/devices/udp_device.h"
#include "palp/studies/psychometric_plot.h"
#include "palp/studies/study_runner.h"
#include "palp/studies/study_stimuli.h"
#include "palp/studies/trace_csv.h"

namespace palp::tool {

namespace fs = std::filesystem;
using namespace palp::haptics;

namespace {

struct StudyArgs {
    std::string study;
    std::string log;
    std::string resume;
    std::string analyse;
    int participant = -1;  ///< -1: 0 for a new log, the log's own for --resume
    std::string responder = "simulated";
    std::int64_t maxTrials = -1;
    std::string traceDir;
    std::string plot;
    bool json = false;
    std::string deviceListen;    ///< a person's device over the bridge: the intervals rendered
    double intervalSeconds = 4;  ///< how long each interval is rendered, s
    ServoArgs servo;             ///< with --device-listen: how the servo thread runs
};

#define PALP_STUDY_SAY(...)                                      \
    do {                                                         \
        if (!globals().quiet) std::fprintf(stderr, __VA_ARGS__); \
    } while (false)

/// Renders one interval on the person's device for @p seconds on the servo thread: @return what
/// was rendered while in contact (the mean stiffness and force), its trace in @p trace.
IntervalFelt renderInterval(StudyStimuli& stimuli, Device& device, const StudyArgs& a,
                            int condition, double level, std::vector<Snapshot>& trace) {
    SessionParams sp = stimuli.sessionParams(condition, level);
    limitStiffnessToDevice(sp.coupling, device.spec(), sp.servo.periodSeconds);
    a.servo.applyTo(sp.servo);
    sp.traceCapacity = 1u << 14;
    Session session(stimuli.sceneFor(condition), device, sp);
    trace.clear();
    Snapshot s;
    const auto drain = [&] {
        while (session.popTrace(s)) trace.push_back(s);
    };
    const auto t0 = std::chrono::steady_clock::now();
    session.start();
    while (std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() <
           a.intervalSeconds) {
        drain();
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    session.stop();
    drain();
    IntervalFelt f;
    for (const Snapshot& t : trace) {
        if (t.contactCount == 0) continue;
        f.meanStiffnessNpm += t.stiffness;
        f.meanForceN += t.force.norm();
        ++f.contactTicks;
    }
    if (f.contactTicks > 0) {
        f.meanStiffnessNpm /= f.contactTicks;
        f.meanForceN /= f.contactTicks;
    }
    return f;
}

/// A person at the terminal: the trial announced on stderr, the answer read from stdin (1 or
/// 2; q stops the study, which --resume continues). With @p device (--device-listen) each
/// interval is first rendered on it for --interval-seconds, announced as it starts; the log's
/// felt columns then hold the mean stiffness rendered in contact (N/m; nan without contact).
StudyResponder terminalResponder(std::shared_ptr<StudyStimuli> stimuli, Device* device,
                                 const StudyArgs& args) {
    return [stimuli, device, args](const StudySpec& spec, const TrialPlan& plan) {
        const StudyCondition& c = spec.conditions[static_cast<std::size_t>(plan.condition)];
        TrialAnswer rendered;
        if (device) {
            std::vector<Snapshot> trace;
            for (int i = 1; i <= 2; ++i) {
                const double level = plan.comparisonInterval == i ? plan.levelPercent : 0.0;
                std::fprintf(stderr, "trial %d (%s), interval %d: touch now (%.3g s)\n",
                             plan.trial + 1, c.name.c_str(), i, args.intervalSeconds);
                const IntervalFelt f =
                    renderInterval(*stimuli, *device, args, plan.condition, level, trace);
                (i == 1 ? rendered.felt1 : rendered.felt2) =
                    f.contactTicks > 0 ? f.meanStiffnessNpm : NAN;
                if (!args.traceDir.empty()) {
                    char name[64];
                    std::snprintf(name, sizeof name, "trial%05d-interval%d.csv", plan.trial, i);
                    const fs::path p = fs::path(args.traceDir) / name;
                    writeTraceCsv(p, trace);
                    rendered.trace += (i == 1 ? "" : ";") + p.string();
                }
            }
        }
        std::fprintf(stderr,
                     "trial %d (%s, %s, trial %d of the condition): which interval was stiffer? "
                     "[1/2, q stops] ",
                     plan.trial + 1, c.name.c_str(), touchModeName(c.touch),
                     plan.conditionTrial + 1);
        const auto start = std::chrono::steady_clock::now();
        TrialAnswer a = rendered;
        std::string line;
        for (;;) {
            if (!std::getline(std::cin, line) || line == "q") {
                a.response = 0;
                break;
            }
            if (line == "1" || line == "2") {
                a.response = line == "1" ? 1 : 2;
                break;
            }
            std::fprintf(stderr, "answer 1 or 2 (q stops): ");
        }
        a.responseSeconds =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        return a;
    };
}

nlohmann::json resultJson(const ConditionResult& r) {
    nlohmann::json j;
    const auto num = [](double v) -> nlohmann::json {
        return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
    };
    j["name"] = r.name;
    j["trials"] = r.trials;
    j["reversals"] = r.reversals;
    j["target"] = r.target;
    j["jnd_procedure_percent"] = num(r.procedureThreshold);
    j["jnd_fit_percent"] = num(r.fitThreshold);
    j["jnd_fit_interval_percent"] = {num(r.fitInterval.lo), num(r.fitInterval.hi)};
    j["weber_fraction_fit"] = num(r.fitThreshold / 100);
    if (r.fit) {
        j["fit"] = {{"shape", perception::shapeName(r.fit->function.shape)},
                    {"alpha", r.fit->function.alpha},
                    {"beta", r.fit->function.beta},
                    {"gamma", r.fit->function.gamma},
                    {"lambda", r.fit->function.lambda},
                    {"deviance", r.fit->deviance},
                    {"converged", r.fit->converged}};
    }
    j["blocks"] = nlohmann::json::array();
    for (const auto& b : r.blocks) j["blocks"].push_back({b.level, b.correct, b.trials});
    if (!r.note.empty()) j["note"] = r.note;
    return j;
}

void report(const StudyArgs& a, const StudySpec& spec, const StudyRunner& runner,
            const std::vector<ConditionResult>& results, const std::string& logPath) {
    std::string order;
    for (int c : runner.order())
        order += (order.empty() ? "" : ", ") + spec.conditions[static_cast<std::size_t>(c)].name;
    if (a.json) {
        nlohmann::json j;
        j["study"] = spec.id;
        j["digest"] = spec.digest;
        j["participant"] = runner.participant();
        j["trials"] = runner.trialsDone();
        j["finished"] = runner.finished();
        j["order"] = order;
        j["method"] = spec.procedure.method == StudyMethod::Quest ? "quest" : "staircase";
        j["log"] = logPath;
        j["conditions"] = nlohmann::json::array();
        for (const auto& r : results) j["conditions"].push_back(resultJson(r));
        if (!a.plot.empty()) {
            j["plot"] = {a.plot + ".png", a.plot + ".svg", a.plot + ".pdf"};
        }
        std::printf("%s\n", j.dump(2).c_str());
        return;
    }
    std::printf("palp study %s: participant %d, %d trials%s (order %s), log %s\n", spec.id.c_str(),
                runner.participant(), runner.trialsDone(), runner.finished() ? "" : " (unfinished)",
                order.c_str(), logPath.c_str());
    const char* procName = spec.procedure.method == StudyMethod::Quest ? "QUEST mean" : "reversals";
    std::printf("%-14s %6s %9s %15s %12s %20s %9s\n", "condition", "trials", "reversals",
                (std::string("JND ") + procName + " %").c_str(), "JND fit %", "interval %",
                "deviance");
    for (const auto& r : results) {
        char interval[48] = "-";
        if (std::isfinite(r.fitInterval.lo))
            std::snprintf(interval, sizeof interval, "[%.3g, %.3g]", r.fitInterval.lo,
                          r.fitInterval.hi);
        std::printf("%-14s %6d %9d %15.3g %12.3g %20s %9.3g\n", r.name.c_str(), r.trials,
                    r.reversals, r.procedureThreshold, r.fitThreshold, interval,
                    r.fit ? r.fit->deviance : NAN);
        if (!r.note.empty()) std::printf("  %s: %s\n", r.name.c_str(), r.note.c_str());
    }
    std::printf("JND: the comparison's increment detected with p = %.4g (fit: %s, gamma 0.5)\n",
                procedureTarget(spec.procedure), perception::shapeName(spec.fit.shape).data());
}

int studyCommand(const StudyArgs& a) {
    const StudySpec spec = loadStudySpec(a.study);
    const int given =
        (a.log.empty() ? 0 : 1) + (a.resume.empty() ? 0 : 1) + (a.analyse.empty() ? 0 : 1);
    if (given != 1)
        throw ValueError(
            "palp study: expected one of --log NEW.csv, --resume LOG.csv or "
            "--analyse LOG.csv, found " +
            std::to_string(given));
    if (!a.traceDir.empty() && !fs::is_directory(a.traceDir))
        throw ValueError("--trace-dir: expected an existing directory, found '" + a.traceDir + "'");
    if (!a.deviceListen.empty() && a.responder != "terminal")
        throw ValueError(
            "--device-listen: expected --responder terminal (a person on the device), found "
            "--responder " +
            a.responder);
    if (a.traceDir.find(',') != std::string::npos || a.traceDir.find(';') != std::string::npos)
        throw ValueError(
            "--trace-dir: expected a path without ',' or ';' (the log's trace column "
            "separators), found '" +
            a.traceDir + "'");
    int participant = a.participant < 0 ? 0 : a.participant;
    if (!a.resume.empty() && a.participant < 0) {
        StudyLogHeader h;
        (void)readStudyLog(a.resume, h);
        participant = h.participant;
    }
    StudyRunner runner(spec, participant);
    std::vector<TrialRecord> trials;
    std::string logPath;
    if (!a.analyse.empty()) {
        StudyLogHeader h;
        trials = readStudyLog(a.analyse, h);
        if (h.study != spec.id || h.digest != spec.digest)
            throw ValueError(a.analyse + ": study: expected '" + spec.id + "' digest " +
                             spec.digest + " (" + a.study + "), found '" + h.study + "' digest " +
                             h.digest);
        StudyRunner logged(spec, h.participant);
        logged.replay(trials, a.analyse);
        const auto results = analyseStudy(spec, trials);
        if (!a.plot.empty())
            writePsychometricPlot(a.plot, results, "palp study " + spec.id, spec.fit.coverage);
        report(a, spec, logged, results, a.analyse);
        return 0;
    }
    // The device's socket before the log: a port in use leaves no new log behind.
    std::optional<UdpDevice> device;
    if (!a.deviceListen.empty()) {
        UdpDeviceParams dp;
        dp.listen = a.deviceListen;
        namingOption("udp device listen address", "--device-listen",
                     [&] { device.emplace(*findDeviceSpec(spec.device), dp); });
        // The bound address on a line of its own (the port chosen for port 0), for the device.
        std::fprintf(stderr, "palp study: listening on udp %s\n", device->address().c_str());
        std::fflush(stderr);
    }
    std::optional<StudyLog> log;
    if (!a.resume.empty()) {
        log.emplace(StudyLog::resume(a.resume, runner.logHeader(), trials));
        runner.replay(trials, a.resume);
        logPath = a.resume;
        PALP_STUDY_SAY("palp study: resumed %s after %zu trials\n", a.resume.c_str(),
                       trials.size());
    } else {
        log.emplace(StudyLog::create(a.log, runner.logHeader()));
        logPath = a.log;
    }
    StudyResponder responder;
    std::shared_ptr<StudyStimuli> stimuli;
    if (a.responder == "terminal") {
        if (device) stimuli = std::make_shared<StudyStimuli>(spec);
        responder = terminalResponder(stimuli, device ? &*device : nullptr, a);
    } else {
        stimuli = std::make_shared<StudyStimuli>(spec);
        responder = simulatedResponder(stimuli, a.traceDir);
    }
    const auto start = std::chrono::steady_clock::now();
    const int ran = runStudyTrials(runner, responder, *log,
                                   a.maxTrials < 0 ? -1 : static_cast<int>(a.maxTrials));
    const double wall =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    {
        StudyLogHeader h;
        trials = readStudyLog(logPath, h);
    }
    PALP_STUDY_SAY("palp study: %d trials in %.2f s%s\n", ran, wall,
                   stimuli && !device ? (", " + std::to_string(stimuli->sessionsRun()) +
                                         " palpation sessions run (felt figures cached per level)")
                                            .c_str()
                                      : "");
    const auto results = analyseStudy(spec, trials);
    if (!a.plot.empty())
        writePsychometricPlot(a.plot, results, "palp study " + spec.id, spec.fit.coverage);
    report(a, spec, runner, results, logPath);
    if (!runner.finished()) {
        std::fprintf(stderr, "palp study: stopped before the end; --resume %s continues\n",
                     logPath.c_str());
        return 3;
    }
    return 0;
}

}  // namespace

Command addStudy(CLI::App& root) {
    auto args = std::make_shared<StudyArgs>();
    CLI::App* app = root.add_subcommand(
        "study",
        "Two-interval forced-choice stiffness study on the stiffness phantom: staircase or "
        "QUEST, simulated observer or a person at the terminal (docs/studies.md)");
    app->add_option("study", args->study, "Study file (JSON)")->required();
    app->add_option("--log", args->log, "New trial log (CSV; an existing file is refused)");
    app->add_option("--resume", args->resume, "Continue the study in this log");
    app->add_option("--analyse", args->analyse, "Only analyse (and plot) this log");
    app->add_option("--participant", args->participant,
                    "Participant number: the row of the Latin square of conditions (default 0; "
                    "with --resume, the log's)")
        ->check(integerIn(0, 1000000));
    app->add_option("--responder", args->responder,
                    "simulated (an observer palpating the phantom) or terminal (1/2 on stdin)")
        ->check(CLI::IsMember({"simulated", "terminal"}))
        ->capture_default_str();
    app->add_option("--max-trials", args->maxTrials,
                    "Run at most this many trials, then stop (exit 3; --resume continues)")
        ->check(integerIn(0, 100000000));
    app->add_option("--trace-dir", args->traceDir,
                    "Write each simulated interval's session trace (CSV) here");
    app->add_option("--plot", args->plot,
                    "Psychometric plot: writes STEM.png, STEM.svg and STEM.pdf");
    app->add_flag("--json", args->json, "Results as JSON on stdout");
    app->add_option("--device-listen", args->deviceListen,
                    "With --responder terminal: render each interval on a person's haptic "
                    "device that sends its state over UDP (bridge protocol, docs/device_bridge.md) "
                    "to this host:port (port 0: any free one, printed)");
    app->add_option("--interval-seconds", args->intervalSeconds,
                    "With --device-listen: how long each interval is rendered, s")
        ->check(CLI::Range(0.05, 600.0))
        ->capture_default_str();
    // With --device-listen: how the servo thread that renders each interval runs.
    addServoOptions(app, args->servo);
    return {app, [args]() -> int { return studyCommand(*args); }};
}

}  // namespace palp::tool
