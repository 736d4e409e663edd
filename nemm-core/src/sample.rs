//! One sample of the damper's signals: the input of [`crate::Estimator::step`] and
//! [`crate::AlphaObserver::step`].
//!
//! The stroke velocity is always given; the other signals are optional, each saying what the
//! step does without it:
//!
//! | field | unit | without it |
//! |---|---|---|
//! | `velocity_m_s` | m/s, positive = extension | (always given) |
//! | `position_m` | m, the position sensor's coordinates | a model with a static force holds the last good position, flagged [`crate::Flags::POSITION_MISSING`]; other models ignore it |
//! | `alpha` | \[-\], oil-loss (condition) level in `[0, 1]` | the estimator's own level ([`crate::Estimator::alpha`]) |
//! | `force_n` | N, measured, positive in tension | the observer treats the sample as a missing measurement ([`crate::ObserverFlags::FORCE_FAULT`]); the estimator never reads it |
//!
//! A present but non-finite value is a sensor fault, flagged by the step as such; it is not
//! the same as an absent one (a non-finite velocity is held, a non-finite position is
//! replaced by the last good one, a non-finite `alpha` is refused, a non-finite force is a
//! force fault).
//!
//! ```
//! use nemm_core::Sample;
//! let s = Sample::new(0.3).with_position(0.012).with_force(850.0);
//! assert_eq!(s.position_m, Some(0.012));
//! assert_eq!(s.alpha, None);
//! assert_eq!(Sample::from(0.3), Sample::new(0.3));
//! ```

/// One sample (module docs): the stroke velocity and the optional position, level and
/// measured force of the same instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Stroke velocity \[m/s\], positive = extension.
    pub velocity_m_s: f32,
    /// Stroke position \[m\] as the position sensor measures it (the coordinates the model
    /// was trained in), for a model with a static force.
    pub position_m: Option<f32>,
    /// This sample's oil-loss (condition) level `alpha` \[-\] in `[0, 1]`; `None`: the
    /// estimator's own level.
    pub alpha: Option<f32>,
    /// Measured damper force \[N\], positive in tension: the observer's input (the
    /// estimator ignores it).
    pub force_n: Option<f32>,
}

impl Sample {
    /// A sample of the stroke velocity \[m/s\] alone.
    #[inline]
    pub const fn new(velocity_m_s: f32) -> Self {
        Self {
            velocity_m_s,
            position_m: None,
            alpha: None,
            force_n: None,
        }
    }

    /// With the stroke position \[m\].
    #[inline]
    pub const fn with_position(mut self, position_m: f32) -> Self {
        self.position_m = Some(position_m);
        self
    }

    /// With this sample's level `alpha` \[-\].
    #[inline]
    pub const fn with_alpha(mut self, alpha: f32) -> Self {
        self.alpha = Some(alpha);
        self
    }

    /// With the measured force \[N\].
    #[inline]
    pub const fn with_force(mut self, force_n: f32) -> Self {
        self.force_n = Some(force_n);
        self
    }
}

impl From<f32> for Sample {
    /// [`Sample::new`].
    #[inline]
    fn from(velocity_m_s: f32) -> Self {
        Self::new(velocity_m_s)
    }
}
