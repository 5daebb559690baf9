//! The simple guesses every STE report shows beside its estimate: the position of the highest
//! reading, and the arena centre. An estimator that cannot beat them has not earned its model.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::layout::Layout;
use crate::ste::posterior::Sample;

/// One guess of the source position, with its error when the source is known.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Guess {
    /// x (m).
    pub x: f64,
    /// y (m).
    pub y: f64,
    /// Distance to the true source (m), when it is known.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error_m: Option<f64>,
}

impl Guess {
    fn at([x, y]: [f64; 2], source: Option<[f64; 2]>) -> Self {
        Self {
            x,
            y,
            error_m: source.map(|s| (x - s[0]).hypot(y - s[1])),
        }
    }
}

/// The baselines of one run or log.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Baselines {
    /// Where the highest reading was taken (the first of equal maxima).
    pub highest_reading: Guess,
    /// The arena's centre.
    pub centre: Guess,
}

impl Baselines {
    /// The baselines of `samples` in `layout`, with errors when `source` is given.
    ///
    /// # Errors
    /// [`Error::Parameter`] when there is no reading.
    pub fn new(layout: &Layout, samples: &[Sample], source: Option<[f64; 2]>) -> Result<Self> {
        let highest = samples
            .iter()
            .fold(None::<&Sample>, |best, s| match best {
                Some(b) if b.value >= s.value => Some(b),
                _ => Some(s),
            })
            .ok_or_else(|| Error::Parameter("no readings: no highest reading".into()))?;
        Ok(Self {
            highest_reading: Guess::at([highest.x, highest.y], source),
            centre: Guess::at([0.5 * layout.width(), 0.5 * layout.height()], source),
        })
    }
}
