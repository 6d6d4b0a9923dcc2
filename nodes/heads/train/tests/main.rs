mod data;
mod motion;
