/// @file coupling.h
/// @brief Between the simulation's forces and a device: force hold or first-order extrapolation,
/// virtual coupling within the passivity bound, and the device-to-world mapping.
/// Implementation: coupling.cpp.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace heartsim::haptics {

enum class ForceInterpolation { hold, extrapolate };
const char* to_string(ForceInterpolation mode);

/// Spring-damper between the device (x_d) and a tool proxy (x_p, mass m_p, damping c_p to
/// ground) that the simulation sees: the proxy feels the tissue force plus K(x_d − x_p) +
/// B(v_d − v_p); the device is sent K(x_p − x_d) + B(v_p − v_d).
struct CouplingSettings {
    bool enabled = false;
    double stiffness_n_per_mm = 0.0;   ///< K
    double damping_n_ms_per_mm = 0.0;  ///< B
    double proxy_mass_g = 10.0;        ///< m_p
    double proxy_damping_n_ms_per_mm = 0.0;  ///< c_p; 0 = 2√(K·m_p) (critical on the spring)
};

/// The passivity bound of a sampled virtual spring-damper (Colgate & Schenkel 1997):
/// b > K·T/2 + B, b the device's physical damping, T the sampling period. Returns K, B with
/// B = b/4 and K = margin · 2(b − B)/T (margin < 1 keeps it strictly inside).
CouplingSettings choose_coupling(double device_damping_n_ms_per_mm, double period_ms, double margin = 0.5);
/// True when b > K·T/2 + B.
bool within_passivity_bound(const CouplingSettings& coupling, double device_damping_n_ms_per_mm, double period_ms);

/// Device frame → world (simulation) frame: x_w = offset + scale · R · x_d, q_w = R · q_d.
/// Forces go back as f_d = force_scale · Rᵀ · f_w.
struct DeviceMapping {
    Eigen::Vector3d offset_mm = Eigen::Vector3d::Zero();
    Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
    double scale = 1.0;
    double force_scale = 1.0;
};

}  // namespace heartsim::haptics
