//! Families of dimensionless basis functions of one state variable (thesis chapter 3).

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize)]
pub enum Basis {
    Const,
}
