/* The core's real type: float (the microcontroller's FPU, the firmware as flown) unless built with
 * -DBW_DOUBLE (the reference build that the lockstep harness holds against the Python core's float64). */
#ifndef BW_REAL_H
#define BW_REAL_H

#include <math.h>

#ifdef BW_DOUBLE
typedef double bw_real;
#define BW_SQRT sqrt
#define BW_SIN sin
#define BW_COS cos
#define BW_ATAN2 atan2
#define BW_EXP exp
#define BW_LOG log
#define BW_FABS fabs
#define BW_FMOD fmod
#define BW_POW pow
#define BW_HYPOT hypot
#else
typedef float bw_real;
#define BW_SQRT sqrtf
#define BW_SIN sinf
#define BW_COS cosf
#define BW_ATAN2 atan2f
#define BW_EXP expf
#define BW_LOG logf
#define BW_FABS fabsf
#define BW_FMOD fmodf
#define BW_POW powf
#define BW_HYPOT hypotf
#endif
#define BW_R(v) ((bw_real)(v))

#endif
