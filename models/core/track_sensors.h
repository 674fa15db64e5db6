/* track_sensors.h -- point track sensors (Boynik et al.) as models/chain.py and
 * models/plant/track_sensors.py compute them: a pair of sensors a base b apart,
 * speed = b / (t2' - t1') from a timer's stamps.
 * Pure functions of their arguments (the noise draws are the caller's); nothing allocates. */
#ifndef RAILCAR_TRACK_SENSORS_H
#define RAILCAR_TRACK_SENSORS_H

/* models.chain.TrackSensorConfig.speed_std(v) = track_sensor_speed_std: the std [m/s] of a
 * measured speed at v [m/s], v^2 / b sqrt(delta^2/6 + 2 jitter^2) (base [m], resolution and
 * jitter [s]) */
double rc_track_speed_std(double v, double base, double resolution, double jitter);

/* models.plant.track_sensors.quantise_time(t, resolution) with phase 0 [s]: t itself at resolution 0 */
double rc_track_quantise(double t, double resolution);

/* float(models.plant.track_sensors.speed_from_times(t1, t2, base, resolution, 0.0, j1, j2)) [m/s]:
 * +inf when both stamps fall on one tick (or the second before the first) */
double rc_track_speed_from_times(double t1, double t2, double base, double resolution,
                                 double j1, double j2);

/* models.chain._hermite_crossing: the time in [t0, t1] [s] at which the cubic Hermite path
 * through (x0, v0), (x1, v1) reaches the distance d [m] (50 bisections) */
double rc_track_hermite_crossing(double t0, double x0, double v0, double t1, double x1, double v1,
                                 double d);

#endif
