/* track.h -- the grade profile i(X) and the speed profile V_zad(X) of models/plant/track.py.
 * The arrays are the caller's (the chain keeps its own copy); nothing here allocates. */
#ifndef RAILCAR_TRACK_H
#define RAILCAR_TRACK_H

typedef struct {
    const double *distances;   /* [m], strictly increasing, n >= 1 */
    const double *grades;      /* [permille] */
    const double *cum;         /* integral of the grade at each breakpoint [permille m], n values
                                  (GradeProfile._cum; rc_grade_cumulate fills it) */
    long n;
} rc_grade_profile;

typedef struct {
    const double *distances;   /* [m], strictly increasing, n >= 1 */
    const double *speeds;      /* [m/s] */
    long n;                    /* 0: no speed profile */
} rc_speed_profile;

/* GradeProfile.__post_init__'s _cum into cum[n] */
void rc_grade_cumulate(const double *distances, const double *grades, long n, double *cum);
/* The chains' own copy of the profiles in one allocation (*buffer, freed by the caller): grade
 * distances, grades and their integral; speed distances and speeds (speed_n 0: none, speed->n 0).
 * 0, or -1 when grade_n < 1 or speed_n < 0 or memory runs out (*buffer NULL). */
int rc_profiles_copy(const double *grade_distances, const double *grades, long grade_n,
                     const double *speed_distances, const double *speeds, long speed_n,
                     double **buffer, rc_grade_profile *grade, rc_speed_profile *speed);
/* GradeProfile.at(x) [permille] */
double rc_grade_at(const rc_grade_profile *g, double x);
/* GradeProfile.average(x, length) [permille] */
double rc_grade_average(const rc_grade_profile *g, double x, double length);
/* SpeedProfile.at(x) [m/s] (n >= 1) */
double rc_speed_at(const rc_speed_profile *s, double x);

#endif
