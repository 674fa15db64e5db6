/* singer.c -- see singer.h; the bodies of models/filtering/singer.py's scalar path, expression for
 * expression (operands, order and association kept; x ** n is libm pow as in CPython). */
#include "rc_fp_contract.h"
#include <string.h>

#include "fpmath.h"
#include "singer.h"

/* singer._COEFFS: Taylor coefficients of each function, exact rationals rounded once (printed
 * with repr(); tests/model_tests/core/test_core_singer.py checks them against Python's) */
static const double COEFFS[RC_SF_COUNT][RC_SINGER_SERIES_TERMS] = {
    {   /* phi1 */
    1.0, -0.5, 0.16666666666666666, -0.041666666666666664,
    0.008333333333333333, -0.001388888888888889, 0.0001984126984126984, -2.48015873015873e-05,
    2.7557319223985893e-06, -2.755731922398589e-07, 2.505210838544172e-08, -2.08767569878681e-09,
    1.6059043836821613e-10, -1.1470745597729725e-11, 7.647163731819816e-13, -4.779477332387385e-14,
    2.8114572543455206e-15, -1.5619206968586225e-16, 8.22063524662433e-18, -4.110317623312165e-19,
    1.9572941063391263e-20, -8.896791392450574e-22, 3.868170170630684e-23, -1.6117375710961184e-24,
    6.446950284384474e-26, -2.4795962632247976e-27, 9.183689863795546e-29, -3.279889237069838e-30,
    1.1309962886447716e-31, -3.7699876288159054e-33, 1.216125041553518e-34, -3.8003907548547434e-36,
    1.151633562077195e-37, -3.387157535521162e-39, 9.67759295863189e-41, -2.6882202662866363e-42,
    7.265460179153071e-44, -1.911963205040282e-45, 4.902469756513544e-47, -1.2256174391283858e-48},
    {   /* phi2 */
    0.5, -0.16666666666666666, 0.041666666666666664, -0.008333333333333333,
    0.001388888888888889, -0.0001984126984126984, 2.48015873015873e-05, -2.7557319223985893e-06,
    2.755731922398589e-07, -2.505210838544172e-08, 2.08767569878681e-09, -1.6059043836821613e-10,
    1.1470745597729725e-11, -7.647163731819816e-13, 4.779477332387385e-14, -2.8114572543455206e-15,
    1.5619206968586225e-16, -8.22063524662433e-18, 4.110317623312165e-19, -1.9572941063391263e-20,
    8.896791392450574e-22, -3.868170170630684e-23, 1.6117375710961184e-24, -6.446950284384474e-26,
    2.4795962632247976e-27, -9.183689863795546e-29, 3.279889237069838e-30, -1.1309962886447716e-31,
    3.7699876288159054e-33, -1.216125041553518e-34, 3.8003907548547434e-36, -1.151633562077195e-37,
    3.387157535521162e-39, -9.67759295863189e-41, 2.6882202662866363e-42, -7.265460179153071e-44,
    1.911963205040282e-45, -4.902469756513544e-47, 1.2256174391283858e-48, -2.9893108271424046e-50},
    {   /* phi3 */
    0.16666666666666666, -0.041666666666666664, 0.008333333333333333, -0.001388888888888889,
    0.0001984126984126984, -2.48015873015873e-05, 2.7557319223985893e-06, -2.755731922398589e-07,
    2.505210838544172e-08, -2.08767569878681e-09, 1.6059043836821613e-10, -1.1470745597729725e-11,
    7.647163731819816e-13, -4.779477332387385e-14, 2.8114572543455206e-15, -1.5619206968586225e-16,
    8.22063524662433e-18, -4.110317623312165e-19, 1.9572941063391263e-20, -8.896791392450574e-22,
    3.868170170630684e-23, -1.6117375710961184e-24, 6.446950284384474e-26, -2.4795962632247976e-27,
    9.183689863795546e-29, -3.279889237069838e-30, 1.1309962886447716e-31, -3.7699876288159054e-33,
    1.216125041553518e-34, -3.8003907548547434e-36, 1.151633562077195e-37, -3.387157535521162e-39,
    9.67759295863189e-41, -2.6882202662866363e-42, 7.265460179153071e-44, -1.911963205040282e-45,
    4.902469756513544e-47, -1.2256174391283858e-48, 2.9893108271424046e-50, -7.117406731291439e-52},
    {   /* ww */
    1.0, -1.0, 0.6666666666666666, -0.3333333333333333,
    0.13333333333333333, -0.044444444444444446, 0.012698412698412698, -0.0031746031746031746,
    0.0007054673721340388, -0.00014109347442680775, 2.565335898669232e-05, -4.275559831115387e-06,
    6.577784355562133e-07, -9.39683479366019e-08, 1.2529113058213587e-08, -1.5661391322766984e-09,
    1.8425166262078804e-10, -2.0472406957865337e-11, 2.1549902060910882e-12, -2.1549902060910883e-13,
    2.0523716248486557e-14, -1.8657923862260506e-15, 1.622428161935696e-16, -1.3520234682797467e-17,
    1.0816187746237974e-18, -8.320144420183057e-20, 6.163069940876338e-21, -4.40219281491167e-22,
    3.035995044766669e-23, -2.0239966965111126e-24, 1.30580432032975e-25, -8.161277002060938e-27,
    4.946228486097539e-28, -2.9095461682926696e-29, 1.662597810452954e-30, -9.236654502516412e-32,
    4.992786217576439e-33, -2.627782219777073e-34, 1.3475806255267042e-35, -6.737903127633521e-37},
    {   /* wv */
    0.5, -0.5, 0.2916666666666667, -0.125,
    0.043055555555555555, -0.0125, 0.0031498015873015874, -0.0007027116402116402,
    0.0001408179012345679, -2.5628306878306877e-05, 4.2734721554166e-06, -6.576178451178452e-07,
    9.395687719100417e-08, -1.2528348341840405e-08, 1.5660913375033746e-09, -1.842488511635337e-10,
    2.0472250765795654e-11, -2.1549819854558417e-12, 2.154986095773465e-13, -2.0523696675545493e-14,
    1.8657914965469113e-15, -1.622427775118679e-16, 1.3520233071059896e-17, -1.0816187101542946e-18,
    8.32014417222343e-20, -6.163069849039439e-21, 4.402192782112777e-22, -3.0359950334567064e-23,
    2.023996692741125e-24, -1.3058043191136252e-25, 8.161276998260547e-27, -4.946228484945905e-28,
    2.909546167953954e-29, -1.6625978103561783e-30, 9.23665450224759e-32, -4.992786217503784e-33,
    2.6277822197579536e-34, -1.3475806255218018e-35, 6.737903127621264e-37, -3.2867820134767766e-38},
    {   /* wr */
    0.16666666666666666, -0.16666666666666666, 0.09166666666666666, -0.03611111111111111,
    0.01130952380952381, -0.002976190476190476, 0.0006806657848324515, -0.00013833774250440918,
    2.537778579445246e-05, -4.250507722729945e-06, 6.556907598574265e-07, -9.38077574982337e-08,
    1.2517642312615858e-08, -1.5653744159035164e-09, 1.8420386784746418e-10, -2.0469595500610993e-11,
    2.1548340140214024e-12, -2.154907999738622e-13, 2.0523305216724225e-14, -1.865772813284987e-15,
    1.6224192651443036e-16, -1.352019600109576e-17, 1.0816171628862263e-18, -8.320137973232772e-20,
    6.163067461280075e-21, -4.402191896542683e-22, 3.0359947167777454e-23, -2.023996583411484e-24,
    1.3058042826298738e-25, -8.161276880448434e-27, 4.946228448093631e-28, -2.909546156776334e-29,
    1.6625978070657967e-30, -9.236654492838819e-32, 4.992786214888219e-33, -2.627782219050527e-34,
    1.347580625335508e-35, -6.737903127143274e-37, 3.2867820133572043e-38, -1.5651342921033288e-39},
    {   /* vv */
    0.3333333333333333, -0.25, 0.11666666666666667, -0.041666666666666664,
    0.012301587301587301, -0.003125, 0.0006999559082892416, -0.00014054232804232804,
    2.5603254769921436e-05, -4.2713844797178134e-06, 6.574572546794769e-07, -9.394540644540644e-08,
    1.2527583625467223e-08, -1.5660435427300506e-09, 1.8424603970627936e-10, -2.0472094573725967e-11,
    2.1549737648205952e-12, -2.1549819854558418e-13, 2.052367710260443e-14, -1.865790606867772e-15,
    1.622427388301662e-16, -1.3520231459322325e-17, 1.0816186456847918e-18, -8.320143924263804e-20,
    6.163069757202541e-21, -4.402192749313886e-22, 3.0359950221467433e-23, -2.0239966889711374e-24,
    1.3058043178975e-25, -8.161276994460157e-27, 4.946228483794271e-28, -2.909546167615238e-29,
    1.662597810259402e-30, -9.236654501978767e-32, 4.9927862174311293e-33, -2.6277822197388337e-34,
    1.347580625516899e-35, -6.737903127609008e-37, 3.2867820134737875e-38, -1.5651342921317984e-39},
    {   /* vr */
    0.125, -0.08333333333333333, 0.034722222222222224, -0.011111111111111112,
    0.002951388888888889, -0.000677910052910053, 0.0001380621693121693, -2.535273368606702e-05,
    4.248420047031158e-06, -6.555301694190583e-07, 9.379628675263596e-08, -1.2516877596242676e-08,
    1.5653266211301926e-09, -1.8420105639020982e-10, 2.0469439308541306e-11, -2.154825793386156e-12,
    2.1549038894209988e-13, -2.052328564378316e-14, 1.8657719236058477e-15, -1.6224188783272867e-16,
    1.3520194389358189e-17, -1.0816170984167235e-18, 8.320137725273146e-20, -6.163067369443176e-21,
    4.402191863743792e-22, -3.0359947054677823e-23, 2.0239965796414964e-24, -1.305804281413749e-25,
    8.161276876648044e-27, -4.946228446941997e-28, 2.9095461564376185e-29, -1.6625978069690206e-30,
    9.236654492569997e-32, -4.992786214815564e-33, 2.627782219031407e-34, -1.3475806253306053e-35,
    6.7379031271310174e-37, -3.286782013354215e-38, 1.5651342921026172e-39, -7.279694381942156e-41},
    {   /* rr */
    0.05, -0.027777777777777776, 0.00992063492063492, -0.002777777777777778,
    0.0006558641975308642, -0.00013558201058201059, 2.5102212602212603e-05, -4.225455614344503e-06,
    6.536030841586397e-07, -9.364716705986547e-08, 1.2506171567018128e-08, -1.5646096995303344e-09,
    1.841560730741403e-10, -2.046678404335665e-11, 2.1546778219517165e-12, -2.1548257933861558e-13,
    2.0522894184961894e-14, -1.865753240343924e-15, 1.6224103683529112e-16, -1.3520157319394055e-17,
    1.081615551148655e-18, -8.320131526282488e-20, 6.1630649816838115e-21, -4.402190978173698e-22,
    3.035994388788822e-23, -2.023996470311855e-24, 1.3058042449299976e-25, -8.161276758835931e-27,
    4.9462284100897235e-28, -2.909546145259998e-29, 1.662597803678639e-30, -9.236654483161226e-32,
    4.992786212199998e-33, -2.627782218323981e-34, 1.3475806251443114e-35, -6.737903126653027e-37,
    3.2867820132346424e-38, -1.5651342920734358e-39, 7.279694381872638e-41, -3.3089519917918896e-42}
};

const double *rc_singer_coefficients(int name)
{
    return COEFFS[name];
}

static double series(int name, double x)                 /* _series: Horner */
{
    double acc = 0.0;
    for (int k = RC_SINGER_SERIES_TERMS - 1; k >= 0; k--)
        acc = acc * x + COEFFS[name][k];
    return acc;
}

static rc_status closed(int name, double x, double *out)  /* _closed */
{
    double e1 = rc_exp(-x), e2 = rc_exp(-2.0 * x), p;
    switch (name) {
    case RC_SF_PHI1:
        *out = -rc_expm1(-x) / x;
        return RC_OK;
    case RC_SF_PHI2:
        *out = (x + rc_expm1(-x)) / (x * x);
        return RC_OK;
    case RC_SF_PHI3:
        if (rc_power(x, 3, &p))
            return RC_MATH;
        *out = (1.0 - x + 0.5 * x * x - e1) / p;
        return RC_OK;
    case RC_SF_WW:
        *out = -rc_expm1(-2.0 * x) / (2.0 * x);
        return RC_OK;
    case RC_SF_WV: {
        double d = 2.0 * x * x;                   /* 0 below x ~ 1e-162: ZeroDivisionError */
        if (rc_power(rc_expm1(-x), 2, &p) || d == 0.0)
            return RC_MATH;
        *out = p / d;
        return RC_OK;
    }
    case RC_SF_WR:
        if (rc_power(x, 3, &p))
            return RC_MATH;
        *out = (-rc_expm1(-2.0 * x) - 2.0 * x * e1) / (2.0 * p);
        return RC_OK;
    case RC_SF_VV:
        if (rc_power(x, 3, &p))
            return RC_MATH;
        *out = (2.0 * x - 3.0 + 4.0 * e1 - e2) / (2.0 * p);
        return RC_OK;
    case RC_SF_VR:
        if (rc_power(x, 4, &p))
            return RC_MATH;
        *out = (x * x - 2.0 * x + 1.0 - 2.0 * e1 + 2.0 * x * e1 + e2) / (2.0 * p);
        return RC_OK;
    default: {                                            /* RC_SF_RR */
        double p3;
        if (rc_power(x, 3, &p3) || rc_power(x, 5, &p))
            return RC_MATH;
        *out = (2.0 * p3 / 3.0 - 2.0 * x * x + 2.0 * x + 1.0 - e2 - 4.0 * x * e1) / (2.0 * p);
        return RC_OK;
    }
    }
}

rc_status rc_singer_f(int name, double x, double *out)   /* _f */
{
    int always_closed = name == RC_SF_PHI1 || name == RC_SF_WW || name == RC_SF_WV;
    if (x >= RC_SINGER_SERIES_SWITCH || (x > 0.0 && always_closed))
        return closed(name, x, out);
    *out = series(name, x);
    return RC_OK;
}

static rc_status check_step(double alpha, double dt, double *x)   /* _check_step */
{
    if (!(alpha > 0.0 && isfinite(alpha)))
        return RC_MATH;
    if (!(dt >= 0.0 && isfinite(dt)))
        return RC_MATH;
    *x = alpha * dt;
    return RC_OK;
}

rc_status rc_singer_discretisation(double alpha, double dt, double sigma_w, double m_w,
                                   double *Phi, double *Q, double *u)
{
    static const int names[3][3] = {{RC_SF_WW, RC_SF_WV, RC_SF_WR},
                                    {RC_SF_WV, RC_SF_VV, RC_SF_VR},
                                    {RC_SF_WR, RC_SF_VR, RC_SF_RR}};
    double x, f, scale[3], k;
    if (check_step(alpha, dt, &x))
        return RC_MATH;
    /* _transition */
    Phi[0] = rc_exp(-x);
    Phi[1] = Phi[2] = Phi[5] = 0.0;
    if (rc_singer_f(RC_SF_PHI1, x, &f))
        return RC_MATH;
    Phi[3] = dt * f;
    Phi[4] = 1.0;
    if (rc_singer_f(RC_SF_PHI2, x, &f))
        return RC_MATH;
    Phi[6] = dt * dt * f;
    Phi[7] = dt;
    Phi[8] = 1.0;
    /* _process_noise */
    if (!(sigma_w >= 0.0 && isfinite(sigma_w)))
        return RC_MATH;
    scale[0] = 1.0;
    scale[1] = dt;
    scale[2] = dt * dt;
    k = 2.0 * x * sigma_w * sigma_w;
    for (int i = 0; i < 3; i++)
        for (int j = i; j < 3; j++) {
            if (rc_singer_f(names[i][j], x, &f))
                return RC_MATH;
            Q[3 * i + j] = Q[3 * j + i] = k * scale[i] * scale[j] * f;
        }
    /* _mean_input */
    u[0] = m_w * -rc_expm1(-x);
    if (rc_singer_f(RC_SF_PHI2, x, &f))
        return RC_MATH;
    u[1] = m_w * (dt * x * f);
    if (rc_singer_f(RC_SF_PHI3, x, &f))
        return RC_MATH;
    u[2] = m_w * (dt * dt * x * f);
    return RC_OK;
}

/* _dot over strided operands: a[0] b[0] + a[sa] b[sb] + ... left to right */
static double dot(const double *a, int sa, const double *b, int sb, int n)
{
    double s = a[0] * b[0];
    for (int i = 1; i < n; i++)
        s += a[i * sa] * b[i * sb];
    return s;
}

static void project(double *x, const double *P)          /* _project */
{
    double v = x[1], pvv;
    if (!(v < 0.0))
        return;
    pvv = P[4];
    if (pvv > 0.0) {
        x[0] = x[0] - P[1] / pvv * v;
        x[1] = x[1] - P[4] / pvv * v;
        x[2] = x[2] - P[7] / pvv * v;
    }
    x[1] = 0.0;
}

static void symmetric(const double *M, double *out)      /* _symmetric */
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            out[3 * i + j] = 0.5 * (M[3 * i + j] + M[3 * j + i]);
}

void rc_singer_init(rc_singer *s, double tau, double sigma_w, double m_w, const double *x0,
                    const double *P0, int clip)
{
    s->tau = tau;
    s->sigma_w = sigma_w;
    s->m_w = m_w;
    s->clip = clip;
    memcpy(s->x, x0, sizeof s->x);
    memcpy(s->P, P0, sizeof s->P);
    if (clip)
        project(s->x, s->P);
    s->nis = NAN;
    s->has_disc = 0;
}

rc_status rc_singer_predict(rc_singer *s, double dt)     /* SingerFilter.predict, _predict */
{
    double xp[3], T[9], M[9];
    const double *Phi = s->Phi, *Q = s->Q, *u = s->u, *P = s->P;
    dt = dt + 0.0;
    if (!(s->has_disc && dt == s->disc_dt)) {
        double Phi1[9], Q1[9], u1[3];
        if (rc_singer_discretisation(1.0 / s->tau, dt, s->sigma_w, s->m_w, Phi1, Q1, u1))
            return RC_MATH;
        memcpy(s->Phi, Phi1, sizeof Phi1);
        memcpy(s->Q, Q1, sizeof Q1);
        memcpy(s->u, u1, sizeof u1);
        s->disc_dt = dt;
        s->has_disc = 1;
    }
    for (int i = 0; i < 3; i++)
        xp[i] = dot(Phi + 3 * i, 1, s->x, 1, 3) + u[i];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            T[3 * i + j] = dot(Phi + 3 * i, 1, P + j, 3, 3);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            M[3 * i + j] = dot(T + 3 * i, 1, Phi + 3 * j, 1, 3) + Q[3 * i + j];
    symmetric(M, s->P);
    if (s->clip)
        project(xp, s->P);
    memcpy(s->x, xp, sizeof xp);
    return RC_OK;
}

rc_status rc_singer_update(rc_singer *s, int m, const double *z, const double *H,
                           const double *R)                /* _update */
{
    double G[6] = {0}, S[4] = {0}, y[2] = {0}, K[6] = {0}, inv[4], w[2], xn[3], A[9], T[9];
    double KR[6] = {0}, Pn[9], nis;
    const double *P = s->P, *x = s->x;
    if (m != 1 && m != 2)
        return RC_MATH;
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < m; a++)
            G[m * i + a] = dot(P + 3 * i, 1, H + 3 * a, 1, 3);
    for (int a = 0; a < m; a++)
        for (int b = 0; b < m; b++)
            S[m * a + b] = dot(H + 3 * a, 1, G + b, m, 3) + R[m * a + b];
    for (int a = 0; a < m; a++)
        y[a] = z[a] - dot(H + 3 * a, 1, x, 1, 3);
    if (m == 1) {
        double sc = S[0];
        if (sc == 0.0)
            return RC_MATH;
        K[0] = G[0] / sc;
        K[1] = G[1] / sc;
        K[2] = G[2] / sc;
        nis = y[0] * (y[0] / sc);
    } else {
        double det = S[0] * S[3] - S[1] * S[2];
        if (det == 0.0)
            return RC_MATH;
        inv[0] = S[3] / det;
        inv[1] = -S[1] / det;
        inv[2] = -S[2] / det;
        inv[3] = S[0] / det;
        for (int i = 0; i < 3; i++)
            for (int a = 0; a < 2; a++)
                K[2 * i + a] = dot(G + 2 * i, 1, inv + a, 2, 2);
        w[0] = dot(inv, 1, y, 1, 2);
        w[1] = dot(inv + 2, 1, y, 1, 2);
        nis = dot(y, 1, w, 1, 2);
    }
    for (int i = 0; i < 3; i++)
        xn[i] = x[i] + dot(K + m * i, 1, y, 1, m);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            A[3 * i + j] = (i == j ? 1.0 : 0.0) - dot(K + m * i, 1, H + j, 3, m);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            T[3 * i + j] = dot(A + 3 * i, 1, P + j, 3, 3);
    for (int i = 0; i < 3; i++)
        for (int b = 0; b < m; b++)
            KR[m * i + b] = dot(K + m * i, 1, R + b, m, m);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            Pn[3 * i + j] = dot(T + 3 * i, 1, A + 3 * j, 1, 3)
                            + dot(KR + m * i, 1, K + m * j, 1, m);
    symmetric(Pn, s->P);
    if (s->clip)
        project(xn, s->P);
    memcpy(s->x, xn, sizeof xn);
    s->nis = nis;
    return RC_OK;
}

static const double H_SPEED_ROW[3] = {0.0, 1.0, 0.0};
static const double H_DISTANCE_ROW[3] = {0.0, 0.0, 1.0};

rc_status rc_singer_update_speed(rc_singer *s, double speed, double speed_std)
{
    double R;
    if (rc_power(speed_std, 2, &R))
        return RC_MATH;
    return rc_singer_update(s, 1, &speed, H_SPEED_ROW, &R);
}

rc_status rc_singer_update_distance(rc_singer *s, double distance, double distance_std)
{
    double R;
    if (rc_power(distance_std, 2, &R))
        return RC_MATH;
    return rc_singer_update(s, 1, &distance, H_DISTANCE_ROW, &R);
}

rc_status rc_singer_update_speed_distance(rc_singer *s, double speed, double distance,
                                          double speed_std, double distance_std)
{
    double z[2], H[6], R[4];
    z[0] = speed;
    z[1] = distance;
    memcpy(H, H_SPEED_ROW, sizeof H_SPEED_ROW);
    memcpy(H + 3, H_DISTANCE_ROW, sizeof H_DISTANCE_ROW);
    if (rc_power(speed_std, 2, &R[0]) || rc_power(distance_std, 2, &R[3]))
        return RC_MATH;
    R[1] = R[2] = 0.0;
    return rc_singer_update(s, 2, z, H, R);
}

/* ------------------------------------------------------------------ the settings */

rc_status rc_singer_params(double tau, double p0, double p_plus, double p_minus,
                           double w_max_plus, double w_max_minus, double *m_w, double *sigma_w,
                           rc_error *err)
{
    char r0[32], r1[32], r2[32];
    double a = w_max_plus, b = w_max_minus, probs[3], rest, h, m, var, sq[2], cu[2], s2;
    if (err)
        err->msg[0] = '\0';
    /* FilterConfig.singer_params */
    if (!(tau > 0 && isfinite(tau))) {
        rc_repr(tau, r0, sizeof r0);
        return rc_refuse(err, RC_BAD_CONFIG, "filter.singer_tau must be > 0, got %s",
                         r0);
    }
    /* singer_mixture_moments */
    probs[0] = p0;
    probs[1] = p_plus;
    probs[2] = p_minus;
    for (int i = 0; i < 3; i++)
        if (!(isfinite(probs[i]) && probs[i] >= 0.0)) {
            rc_repr(p0, r0, sizeof r0);
            rc_repr(p_plus, r1, sizeof r1);
            rc_repr(p_minus, r2, sizeof r2);
            return rc_refuse(err, RC_BAD_CONFIG, "filter.singer_*: probabilities must be "
                             "finite and >= 0, got (%s, %s, %s)", r0, r1, r2);
        }
    rest = 1.0 - (0.0 + probs[0] + probs[1] + probs[2]);   /* Python 3.11's sum() */
    if (rest < -1e-12) {
        rc_repr(0.0 + probs[0] + probs[1] + probs[2], r0, sizeof r0);
        return rc_refuse(err, RC_BAD_CONFIG, "filter.singer_*: P0 + P+ + P- must be <= 1, "
                         "got %s", r0);
    }
    rest = rc_max(rest, 0.0);
    if (!(isfinite(a) && isfinite(b) && b <= 0.0 && 0.0 <= a && a > b)) {
        rc_repr(w_max_minus, r0, sizeof r0);
        rc_repr(w_max_plus, r1, sizeof r1);
        return rc_refuse(err, RC_BAD_CONFIG, "filter.singer_*: need w_max_minus <= 0 <= "
                         "w_max_plus and w_max_minus < w_max_plus [m/s^2], got %s, %s", r0, r1);
    }
    h = rest / (a - b);                                                  /* eq. (3) */
    m = probs[1] * a + probs[2] * b + 0.5 * h * (a * a - b * b);         /* eq. (4) */
    if (rc_power(a - m, 2, &sq[0]) || rc_power(b - m, 2, &sq[1]) || rc_power(a - m, 3, &cu[0])
            || rc_power(b - m, 3, &cu[1]))
        return rc_refuse(err, RC_BAD_CONFIG, 
                         "filter.singer_*: (w_max - m_w) ** n overflows (OverflowError)");
    var = (probs[0] * m * m + probs[1] * sq[0] + probs[2] * sq[1]
           + h * (cu[0] - cu[1]) / 3.0);                                 /* eqs. (5), (6) */
    /* SingerParams.__post_init__ (tau checked above) */
    *sigma_w = sqrt(rc_max(var, 0.0));
    *m_w = m;
    if (!(*sigma_w >= 0.0 && isfinite(*sigma_w))) {
        rc_repr(*sigma_w, r0, sizeof r0);
        return rc_refuse(err, RC_BAD_CONFIG, "filter.singer_*: sigma_w must be >= 0 and "
                         "finite [m/s^2], got %s", r0);
    }
    if (!isfinite(m)) {
        rc_repr(m, r0, sizeof r0);
        return rc_refuse(err, RC_BAD_CONFIG, "filter.singer_*: m_w must be finite [m/s^2], "
                         "got %s", r0);
    }
    /* what Python meets later: sigma_w ** 2 at a restart, alpha = 1 / tau at a prediction */
    if (rc_power(*sigma_w, 2, &s2))
        return rc_refuse(err, RC_BAD_CONFIG, 
                         "filter.singer_*: sigma_w ** 2 overflows (OverflowError)");
    if (!isfinite(1.0 / tau)) {
        rc_repr(tau, r0, sizeof r0);
        return rc_refuse(err, RC_BAD_CONFIG, "filter.singer_tau is too small: 1 / tau "
                         "overflows, got %s", r0);
    }
    return RC_OK;
}
