//! The residual error rate of SRDO communication and the SIL limits it implies
//! (EN 50325-5 9.4.2; CiA DSP 304 9.3).
//!
//! EN 50325-5 formula (4) takes the worst-case residual error probability of CAN as
//! 7·10⁻⁹ ≈ 10⁻⁸; formula (5) squares it for Model III, whose SRDO carries the data twice
//! (plain and inverted): R_SL = R(P_CAN)². DSP 304 9.3 turns that into a rate per hour:
//!
//! Λ ≈ 3600 · P · v · (m − 1) · 100
//!
//! with `v` the safety-relevant messages (SRDOs) per second on the network, `m` the safety
//! devices on it (at most 64 producers, EN 50325-5 9.4.1) and the factor 100 the margin that
//! keeps the communication at 1 % of the SIL's budget (SC_REQ_04 asks the same of SimpleCAN).
//! This module takes P from the rounded value 10⁻⁸ (so P = 10⁻¹⁶), not 7·10⁻⁹: it is the
//! larger of the two, and with it the formula gives DSP 304's own figure, at most 44 SRDOs per
//! second for SIL 3 with 64 devices (a test checks it).
//!
//! The manual's table and `safety-config budget` both call [`rate_per_hour`]; there is no
//! second copy of the formula.

/// Worst-case residual error probability of one CAN frame (EN 50325-5 formula (4),
/// 7·10⁻⁹ rounded up as the standard does).
pub const CAN_RESIDUAL_ERROR_PROBABILITY: f64 = 1e-8;

/// Residual error probability of one SRDO, plain and inverted frame (EN 50325-5 formula (5),
/// Model III).
pub const SRDO_RESIDUAL_ERROR_PROBABILITY: f64 =
    CAN_RESIDUAL_ERROR_PROBABILITY * CAN_RESIDUAL_ERROR_PROBABILITY;

/// The margin factor of DSP 304 9.3's formula.
pub const MARGIN: f64 = 100.0;

/// The most SRDO producers a network may have (EN 50325-5 9.4.1).
pub const MAX_PRODUCERS: u32 = 64;

/// A safety integrity level (EN 61508), high demand or continuous mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
pub enum Sil {
    /// SIL 1.
    Sil1,
    /// SIL 2.
    Sil2,
    /// SIL 3.
    Sil3,
}

impl Sil {
    /// All three, lowest first.
    pub const ALL: [Sil; 3] = [Sil::Sil1, Sil::Sil2, Sil::Sil3];

    /// The residual error rate per hour the communication must stay below (DSP 304 9.3:
    /// SIL 3 < 10⁻⁷, SIL 2 < 10⁻⁶, SIL 1 < 10⁻⁵).
    #[must_use]
    pub fn limit_per_hour(self) -> f64 {
        match self {
            Sil::Sil1 => 1e-5,
            Sil::Sil2 => 1e-6,
            Sil::Sil3 => 1e-7,
        }
    }

    /// Its number (1, 2 or 3).
    #[must_use]
    pub fn level(self) -> u8 {
        match self {
            Sil::Sil1 => 1,
            Sil::Sil2 => 2,
            Sil::Sil3 => 3,
        }
    }

    /// The SIL with this number.
    #[must_use]
    pub fn from_level(level: u8) -> Option<Sil> {
        Sil::ALL.into_iter().find(|sil| sil.level() == level)
    }
}

/// The residual error rate per hour of a network with `devices` safety devices exchanging
/// `srdos_per_second` SRDOs per second (DSP 304 9.3). One device alone has no one to
/// mistake a frame for (m − 1 = 0).
#[must_use]
pub fn rate_per_hour(srdos_per_second: f64, devices: u32) -> f64 {
    3600.0
        * SRDO_RESIDUAL_ERROR_PROBABILITY
        * srdos_per_second
        * f64::from(devices.saturating_sub(1))
        * MARGIN
}

/// The most SRDOs per second a network of `devices` safety devices may exchange and stay
/// below `sil`'s limit (∞ for a single device).
#[must_use]
pub fn max_srdos_per_second(sil: Sil, devices: u32) -> f64 {
    sil.limit_per_hour() / rate_per_hour(1.0, devices)
}

/// The highest SIL whose limit the rate stays below, if any.
#[must_use]
pub fn highest_sil(rate_per_hour: f64) -> Option<Sil> {
    Sil::ALL
        .into_iter()
        .rev()
        .find(|sil| rate_per_hour < sil.limit_per_hour())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// DSP 304 9.3: "For SIL 3 is the SRDO transfer limited to 44 SRDO per second ... with 64
    /// safety nodes."
    #[test]
    fn en50325_5_9_4_2_sil3_allows_44_srdos_per_second_with_64_devices() {
        let most = max_srdos_per_second(Sil::Sil3, MAX_PRODUCERS);
        assert_eq!(most.floor(), 44.0, "{most}");
        assert!(rate_per_hour(44.0, 64) < Sil::Sil3.limit_per_hour());
        assert!(rate_per_hour(45.0, 64) >= Sil::Sil3.limit_per_hour());
        assert_eq!(highest_sil(rate_per_hour(44.0, 64)), Some(Sil::Sil3));
        assert_eq!(highest_sil(rate_per_hour(45.0, 64)), Some(Sil::Sil2));
    }

    /// Each SIL allows ten times the traffic of the one above it; beyond SIL 1 nothing.
    #[test]
    fn en50325_5_9_4_2_each_sil_below_allows_ten_times_the_rate() {
        let sil3 = max_srdos_per_second(Sil::Sil3, 64);
        assert!((max_srdos_per_second(Sil::Sil2, 64) / sil3 - 10.0).abs() < 1e-9);
        assert!((max_srdos_per_second(Sil::Sil1, 64) / sil3 - 100.0).abs() < 1e-9);
        assert_eq!(highest_sil(Sil::Sil1.limit_per_hour()), None);
    }

    /// The boundaries of the device count: one device has nothing to confuse, two the
    /// smallest non-zero rate.
    #[test]
    fn en50325_5_9_4_2_a_single_device_has_no_residual_error_rate() {
        assert_eq!(rate_per_hour(1000.0, 1), 0.0);
        assert_eq!(rate_per_hour(1000.0, 0), 0.0);
        assert!(max_srdos_per_second(Sil::Sil3, 1).is_infinite());
        // 3600 · 10⁻¹⁶ · 1 · 1 · 100 = 3.6·10⁻¹¹.
        assert!((rate_per_hour(1.0, 2) - 3.6e-11).abs() < 1e-24);
        assert_eq!(Sil::from_level(3), Some(Sil::Sil3));
        assert_eq!(Sil::from_level(4), None);
    }
}
