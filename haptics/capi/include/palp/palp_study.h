/** @file
 *  palp's C API for perception studies (docs/studies.md): a two-interval forced-choice
 *  stiffness study run one trial at a time by a viewer. The viewer asks for the next trial,
 *  renders each interval on its own device through palp_study_interval_session() (the phantom
 *  and coupling of that interval, with its callbacks), lets the person touch it, and answers
 *  with the interval the person named stiffer (its buttons). Each answer is appended to the log
 *  and synced before the next trial; a study opened again with resume continues the sequence an
 *  uninterrupted run would have given.
 *
 *  Threading: one thread per palp_study; the sessions it makes are ordinary palp_sessions. */
#ifndef PALP_PALP_STUDY_H
#define PALP_PALP_STUDY_H

#include "palp/palp.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct palp_study palp_study;

/** The trial to present. */
typedef struct palp_study_trial {
    int trial;            /**< 0-based over the whole study */
    int condition;        /**< index into the study file's conditions */
    int condition_trial;  /**< 0-based within the condition */
    double level_percent; /**< the comparison's increment over the reference, percent */
    /** 1 or 2: the interval that holds the comparison (never shown to the participant). */
    int comparison_interval;
    double interval_stiffness[2]; /**< k_s of intervals 1 and 2, N/m */
    char condition_name[64];      /**< the condition's name (cut to 63 bytes) */
} palp_study_trial;

/** One condition's results (docs/studies.md, "The results"); NaN where a figure is missing. */
typedef struct palp_study_result {
    char name[64];
    int trials;
    int reversals;
    double jnd_procedure_percent;  /**< the staircase's mean of reversals, or QUEST's mean */
    double jnd_fit_percent;        /**< the psychometric fit's level at the target */
    double jnd_fit_lo, jnd_fit_hi; /**< its bootstrap interval */
} palp_study_result;

/** Opens @p study_file (JSON, checked as by `palp study`) with a log at @p log_file for
 *  @p participant. @p resume == 0: a new log, an existing file refused (PALP_ERROR_IO naming it,
 *  the file untouched); non-zero: continue @p log_file (@p participant < 0: the log's own), a log
 *  of another study, study file, participant or seed refused naming the log and the field.
 *  Errors name the file and the field (PALP_ERROR_INVALID_ARGUMENT, PALP_ERROR_IO,
 *  PALP_ERROR_FORMAT). */
palp_status palp_study_open(const char* study_file, const char* log_file, int participant,
                            int resume, palp_study** out);
void palp_study_close(palp_study* study);

/** 1 when every condition has stopped, 0 otherwise (and for NULL). */
int palp_study_finished(const palp_study* study);

/** The trial to present next. PALP_ERROR_INVALID_ARGUMENT once the study is finished. */
palp_status palp_study_next(const palp_study* study, palp_study_trial* out);

/** A session on the host's device (@p device's callbacks, copied, as for
 *  palp_session_create_host) that renders interval @p interval (1 or 2) of the next trial: the
 *  condition's phantom and its coupling at that interval's stiffness, the study's friction,
 *  1 kHz. Step it or start it, then release it; the next interval needs a session of its own.
 *  The proxy starts where the probe is, so the person should lift the stylus between intervals.
 *  palp_session_get_params reports its mode, stiffness, friction and period; its ray source's
 *  hardness is a ramp palp_session_params cannot express, so palp_session_set_params on it
 *  replaces the study's rendering (do not call it). */
palp_status palp_study_interval_session(palp_study* study, int interval,
                                        const palp_device_callbacks* device, palp_session** out);

/** Answers the next trial: @p response is the interval the person named stiffer (1 or 2),
 *  @p response_seconds the time from the question to the answer (>= 0), @p trace the
 *  intervals' trace files to log (NULL: none; no ',' or ';' inside one path). Appended to the
 *  log and synced; then palp_study_next gives the following trial. */
palp_status palp_study_answer(palp_study* study, int response, double response_seconds,
                              const char* trace);

/** The results of every trial logged so far, one per condition into @p out (up to
 *  @p capacity); @p count receives the number of conditions. */
palp_status palp_study_results(const palp_study* study, palp_study_result* out, int capacity,
                               int* count);

#ifdef __cplusplus
}
#endif

#endif /* PALP_PALP_STUDY_H */
