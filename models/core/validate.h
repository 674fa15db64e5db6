/* validate.h -- a whole configuration checked before a chain is built, with the Python chain's
 * messages (the text of the ValueError RailCarChain / EstimatorChain raise; the pythonfmu FMU
 * prepends "initialisation failed: ", adapter.initialise). For native FMUs: the C core itself
 * trusts its configuration (rc_chain_init, rc_estchain_init), so call these first.
 *
 * The rules are checked in the order the Python chain meets them, and the first one that fails
 * is reported: RailCarChain.__init__ = ChainConfig.validate (VehicleParams, TrackSensorConfig,
 * seed, sensor.sample_period, car.initial_*, solver.step vs sensor.sample_period), the start
 * time, CarPlant (solver.step, car.process_noise_psd), then build_estimator: IdentifierConfig,
 * FilterConfig (kind, Singer settings, speed profile), StationConfig. EstimatorChain:
 * TrackSensorConfig, then build_estimator with dt = 1.
 *
 * Options the core does not cover (est.method 1 and 3) are
 * refused where IdentifierConfig.validate checks that option's value, with a message naming
 * the parameter and value and the pythonfmu FMU that runs them (RailCar.fmu or
 * RailCarEstimator.fmu). So every message before that point is Python's, byte for byte; for
 * those options Python would go on to checks of its own (CoastEKFConfig, ProcessNoiseBank).
 *
 * Values are written as Python's repr() / str() writes them (rc_repr). Existing validators are
 * called, not copied: rc_plant_validate (plant.c), rc_filter_validate (filter.c, which calls
 * rc_singer_params, singer.c).
 *
 * est.slope_window is not in rc_chain_config / rc_estchain_config (railcar.h): it is passed
 * on its own (IdentifierConfig.validate checks it for every est.method). */
#ifndef RAILCAR_VALIDATE_H
#define RAILCAR_VALIDATE_H

#include "railcar.h"

/* The whole RailCarChain configuration: RC_OK, or RC_BAD_CONFIG with the first bad setting
 * named in err. cfg->identifier.dt and .speed_std and cfg->filter.length are not read: the chain
 * takes them from sensor.sample_period, sensor.speed_std and car.length (build_estimator). */
rc_status rc_chain_validate(const rc_chain_config *cfg, long slope_window, int has_speed_profile,
                            rc_error *err);
/* The whole EstimatorChain configuration (RailCarEstimator; no sensor.track_spacing): as
 * above; cfg->identifier.dt and .speed_std are not read (1 s and sensor.speed_std). */
rc_status rc_estchain_validate(const rc_estchain_config *cfg, long slope_window,
                               int has_speed_profile, rc_error *err);

/* The parts, for hosts that build a part alone. */
/* TrackSensorConfig.validate (spacing 0: no sensors) */
rc_status rc_track_sensors_validate(double spacing, double base, double resolution, double jitter,
                                    rc_error *err);
/* IdentifierConfig.validate: every est.method value Python knows is accepted here */
rc_status rc_ident_validate(const rc_ident_config *cfg, int method, int physical,
                            int sigma2_method, long slope_window, rc_error *err);
/* StationConfig.validate */
rc_status rc_station_validate(const rc_station_config *cfg, rc_error *err);

#endif
