//! The paper's III.A pipeline on real lips: GRID speaker s1's lip contour in every video frame
//! (the tracker's 12 outer and 8 inner lip points, head motion taken out as in
//! [`crate::lipsync::lips`]: eye line level, outer-eye distance the unit; then centred on the
//! outer lip's centroid, since the nose-to-mouth distance on screen changes with every nod and
//! no mouth shape explains it), viseme key shapes from the contours at the centres of the
//! phones of each viseme (phones from `tools/align_grid.py`), and Table I: the convex
//! decomposition (Eq. 1-3) of held-out frames onto those shapes.

use std::path::Path;

use super::corpus::{PhoneSegment, read_phones};
use super::grid::{
    GridError, VIDEO_FPS, clip_names, format_error, lips_at, parse_track, read_tracks, s1_held_out,
};
use crate::lipsync::decompose::{DecomposeError, PointTrack};
use crate::lipsync::lips::LipTargets;
use crate::lipsync::lips::landmark::{LEFT_EYE_OUTER, NOSE_TIP, RIGHT_EYE_OUTER};
use crate::lipsync::mouth::VisemeShapes;
use crate::lipsync::phones::{PhoneTarget, phone_target};
use crate::vocab::{VISEME_COUNT, Viseme};

/// The lip contour's landmarks: the outer lip from the right corner over the upper lip and
/// back under the lower, then the inner lip the same way round.
pub const CONTOUR: [usize; 20] = [
    61, 40, 37, 0, 267, 270, 291, 321, 314, 17, 84, 91, 78, 82, 13, 312, 308, 317, 14, 87,
];
/// The outer lip's points come first in [`CONTOUR`].
pub const OUTER_POINTS: usize = 12;
/// Coordinates of one contour frame (x, y per point, in eye widths).
pub const CONTOUR_COORDS: usize = 2 * CONTOUR.len();
/// The phone rate of the alignment files (16 kHz samples).
pub const PHONE_RATE: f64 = 16_000.0;

/// One clip: its normalised contour and lip measures per video frame (`None` where untracked)
/// and its phone centres with their viseme.
#[derive(Debug, Clone)]
pub struct ContourClip {
    pub name: String,
    pub contours: Vec<Option<Vec<f32>>>,
    /// The lip measures of each video frame ([`crate::train::grid::parse_track`]).
    pub lips: Vec<Option<LipTargets>>,
    pub centres: Vec<(f64, Viseme)>,
}

/// The normalised lip contour of each video frame of a tracks CSV.
pub fn parse_contours(text: &str, path: &Path) -> Result<Vec<Option<Vec<f32>>>, GridError> {
    let wanted = |column: &dyn Fn(&str) -> Result<usize, GridError>| {
        let xy = |index: usize| -> Result<[usize; 2], GridError> {
            Ok([
                column(&format!("x_{index}"))?,
                column(&format!("y_{index}"))?,
            ])
        };
        let references = [xy(NOSE_TIP)?, xy(RIGHT_EYE_OUTER)?, xy(LEFT_EYE_OUTER)?];
        let lips: Vec<[usize; 2]> = CONTOUR.map(xy).into_iter().collect::<Result<_, _>>()?;
        Ok((references, lips))
    };
    read_tracks(text, path, wanted, |(references, lips), row| {
        let fields = &row.fields;
        let point = |[cx, cy]: [usize; 2]| -> Result<[f32; 2], GridError> {
            let parse = |c: usize| {
                fields[c]
                    .parse::<f32>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| row.error(format!("{:?} is not a number", fields[c])))
            };
            Ok([parse(cx)?, parse(cy)?])
        };
        let [nose, right_eye, left_eye] = [
            point(references[0])?,
            point(references[1])?,
            point(references[2])?,
        ];
        let (dx, dy) = (left_eye[0] - right_eye[0], left_eye[1] - right_eye[1]);
        let unit = dx.hypot(dy);
        if unit < 1e-3 {
            return Err(row.error("the outer eye corners coincide".into()));
        }
        let (c, s) = (dx / unit, dy / unit);
        let mut contour = Vec::with_capacity(CONTOUR_COORDS);
        for &cols in lips {
            let [px, py] = point(cols)?;
            let (x, y) = (px - nose[0], py - nose[1]);
            contour.push((c * x + s * y) / unit);
            contour.push((-s * x + c * y) / unit);
        }
        let outer = &contour[..2 * OUTER_POINTS];
        let centroid =
            [0, 1].map(|k| outer.iter().skip(k).step_by(2).sum::<f32>() / OUTER_POINTS as f32);
        for (i, x) in contour.iter_mut().enumerate() {
            *x -= centroid[i % 2];
        }
        Ok(contour)
    })
}

/// The contour at `t_s` seconds, linearly between the two nearest video frames (`None` where
/// either is untracked or `t_s` is outside the video).
pub fn contour_at(video: &[Option<Vec<f32>>], t_s: f64) -> Option<Vec<f32>> {
    let position = t_s * VIDEO_FPS - 0.5;
    let last = video.len().checked_sub(1)? as f64;
    if !(-0.5..=last + 0.5).contains(&position) {
        return None;
    }
    let position = position.clamp(0.0, last);
    let i = position.floor() as usize;
    let frac = (position - i as f64) as f32;
    let a = video[i].as_ref()?;
    if frac == 0.0 {
        return Some(a.clone());
    }
    let b = video.get(i + 1)?.as_ref()?;
    Some(a.iter().zip(b).map(|(x, y)| x + frac * (y - x)).collect())
}

/// The centre of each phone (seconds) with the viseme it aims at: a diphthong's two halves at
/// a quarter and three quarters of it; phones without a shape of their own are left out.
pub fn phone_centres(phones: &[PhoneSegment]) -> Vec<(f64, Viseme)> {
    let mut out = Vec::new();
    for p in phones {
        let at = |f: f64| (p.start as f64 + f * (p.end - p.start) as f64) / PHONE_RATE;
        match phone_target(&p.phone) {
            Ok(PhoneTarget::Single(v)) => out.push((at(0.5), v)),
            Ok(PhoneTarget::Glide(a, b)) => {
                out.push((at(0.25), a));
                out.push((at(0.75), b));
            }
            Ok(PhoneTarget::Transparent) | Err(_) => {}
        }
    }
    out
}

/// s1's clips that have both a track and a phone file, in name order, with whether each is
/// held out (every tenth by name, the rule of [`s1_held_out`] over all s1 tracks).
pub fn load_s1(data: &Path, phones: &Path) -> Result<Vec<(ContourClip, bool)>, GridError> {
    let tracks = data.join("s1").join("tracks");
    let names = clip_names(&tracks, ".csv")?;
    let mut clips = Vec::new();
    for (index, name) in names.into_iter().enumerate() {
        let phn = phones.join(format!("{name}.phn"));
        if !phn.is_file() {
            continue;
        }
        let path = tracks.join(format!("{name}.csv"));
        let text = crate::input::read_to_string(&path, crate::input::MAX_INPUT_BYTES)?;
        let segments = read_phones(&phn).map_err(|e| format_error(&phn, e.to_string()))?;
        clips.push((
            ContourClip {
                contours: parse_contours(&text, &path)?,
                lips: parse_track(&text, &path)?,
                centres: phone_centres(&segments),
                name,
            },
            s1_held_out(index),
        ));
    }
    if clips.is_empty() {
        return Err(format_error(
            phones,
            "no s1 clip has a phone file here (run tools/align_grid.py)",
        ));
    }
    Ok(clips)
}

/// The other speakers' clips: contours only (their phones are not known).
pub fn load_other(data: &Path) -> Result<Vec<ContourClip>, GridError> {
    let tracks = data.join("other-speakers").join("tracks");
    let io = |source| GridError::Io {
        path: tracks.clone(),
        source,
    };
    let mut paths: Vec<_> = std::fs::read_dir(&tracks)
        .map_err(io)?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "csv"))
        .collect();
    paths.sort();
    paths
        .iter()
        .map(|path| {
            let text = crate::input::read_to_string(path, crate::input::MAX_INPUT_BYTES)?;
            Ok(ContourClip {
                name: path
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default(),
                contours: parse_contours(&text, path)?,
                lips: parse_track(&text, path)?,
                centres: Vec::new(),
            })
        })
        .collect()
}

/// How a viseme's key shape is made from the contours at its phone centres.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeyRule {
    /// Their mean.
    Mean,
    /// The mean of the clearest quarter: those that lie furthest from the mean of all phone
    /// centres along the direction of the viseme's own mean (the paper picks its key frames
    /// by hand where each viseme shows clearly; a plain mean is pulled towards the average
    /// mouth by coarticulation and alignment error).
    ClearestQuarter,
}

/// Key shapes by `rule` from the contours at the phone centres, `shift_s` later (lips that
/// trail the sound are looked for later), with the number of centres per viseme; visemes with
/// fewer than `min_count` centres get no shape.
pub fn key_shapes(
    clips: &[&ContourClip],
    shift_s: f64,
    min_count: usize,
    rule: KeyRule,
) -> Result<(VisemeShapes, [usize; VISEME_COUNT]), DecomposeError> {
    let mut found: Vec<Vec<Vec<f32>>> = vec![Vec::new(); VISEME_COUNT];
    for clip in clips {
        for &(t, viseme) in &clip.centres {
            if let Some(contour) = contour_at(&clip.contours, t + shift_s) {
                found[viseme.index()].push(contour);
            }
        }
    }
    let counts: [usize; VISEME_COUNT] = std::array::from_fn(|v| found[v].len());
    let overall = mean(found.iter().flatten(), CONTOUR_COORDS);
    let shapes = Viseme::ALL
        .iter()
        .filter(|v| counts[v.index()] >= min_count.max(1))
        .map(|&v| {
            let frames = &found[v.index()];
            let own = mean(frames.iter(), CONTOUR_COORDS);
            let shape = match rule {
                KeyRule::Mean => own,
                KeyRule::ClearestQuarter => clearest_quarter(frames, &own, &overall),
            };
            (v, shape)
        })
        .collect();
    Ok((VisemeShapes::new(2, shapes)?, counts))
}

/// The mean of the quarter of `frames` (whose mean is `own`) that lie furthest from `overall`
/// along `own - overall` ([`KeyRule::ClearestQuarter`]).
fn clearest_quarter(frames: &[Vec<f32>], own: &[f32], overall: &[f32]) -> Vec<f32> {
    let direction: Vec<f32> = own.iter().zip(overall).map(|(a, b)| a - b).collect();
    let along = |f: &Vec<f32>| -> f32 {
        f.iter()
            .zip(overall)
            .zip(&direction)
            .map(|((x, m), d)| (x - m) * d)
            .sum()
    };
    let mut ranked: Vec<(f32, &Vec<f32>)> = frames.iter().map(|f| (along(f), f)).collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
    mean(
        ranked.iter().take(frames.len().div_ceil(4)).map(|r| r.1),
        own.len(),
    )
}

/// How s1's lips stand at the centres of one viseme's phones, relative to his rest shape:
/// per [`LipTargets::NAMES`] measure (aperture, width, protrusion, lower_lip_back; eye widths).
#[derive(Debug, Clone, PartialEq)]
pub struct VisemeLips {
    pub viseme: Viseme,
    pub centres: usize,
    /// The mean over the centres.
    pub mean: [f32; 4],
    /// Their standard deviation.
    pub sd: [f32; 4],
    /// The mean of the clearest quarter ([`KeyRule::ClearestQuarter`] on the four measures,
    /// each in units of its spread over all centres).
    pub clear: [f32; 4],
}

/// Each viseme's lip measures at its phone centres (`shift_s` later), each less its clip's rest
/// shape: the mean of the clip's lips at its silence centres (the pauses before and after the
/// sentence). Clips without a tracked silence centre are left out; visemes with fewer than
/// `min_count` centres get no row. Also returns the rest shape averaged over the clips used
/// (absolute, eye widths). Silence itself is the rest, so it has no row.
pub fn viseme_lips(
    clips: &[&ContourClip],
    shift_s: f64,
    min_count: usize,
) -> ([f32; 4], Vec<VisemeLips>) {
    let mut found: Vec<Vec<Vec<f32>>> = vec![Vec::new(); VISEME_COUNT];
    let mut rests = Vec::new();
    for clip in clips {
        let at = |t: f64| lips_at(&clip.lips, t + shift_s).map(|l| l.values());
        let silent: Vec<[f32; 4]> = clip
            .centres
            .iter()
            .filter(|(_, v)| *v == Viseme::Sil)
            .filter_map(|&(t, _)| at(t))
            .collect();
        if silent.is_empty() {
            continue;
        }
        let rest: [f32; 4] =
            std::array::from_fn(|k| silent.iter().map(|l| l[k]).sum::<f32>() / silent.len() as f32);
        rests.push(rest.to_vec());
        for &(t, viseme) in clip.centres.iter().filter(|(_, v)| *v != Viseme::Sil) {
            if let Some(l) = at(t) {
                found[viseme.index()].push((0..4).map(|k| l[k] - rest[k]).collect());
            }
        }
    }
    let rest = mean4(&rests);
    let all: Vec<Vec<f32>> = found.iter().flatten().cloned().collect();
    let overall = mean4(&all);
    let sd_all = sd4(&all, &overall).map(|s| if s > 0.0 { s } else { 1.0 });
    let scaled = |f: &[f32]| -> Vec<f32> { (0..4).map(|k| f[k] / sd_all[k]).collect() };
    let rows = Viseme::ALL
        .iter()
        .filter(|v| found[v.index()].len() >= min_count.max(1))
        .map(|&viseme| {
            let frames = &found[viseme.index()];
            let mean = mean4(frames);
            let standard: Vec<Vec<f32>> = frames.iter().map(|f| scaled(f)).collect();
            let clear = clearest_quarter(&standard, &scaled(&mean), &scaled(&overall));
            VisemeLips {
                viseme,
                centres: frames.len(),
                sd: sd4(frames, &mean),
                clear: std::array::from_fn(|k| clear[k] * sd_all[k]),
                mean,
            }
        })
        .collect();
    (rest, rows)
}

fn mean4(frames: &[Vec<f32>]) -> [f32; 4] {
    let n = frames.len().max(1) as f64;
    std::array::from_fn(|k| (frames.iter().map(|f| f64::from(f[k])).sum::<f64>() / n) as f32)
}

fn sd4(frames: &[Vec<f32>], mean: &[f32; 4]) -> [f32; 4] {
    let n = frames.len().max(1) as f64;
    std::array::from_fn(|k| {
        let var = frames
            .iter()
            .map(|f| (f64::from(f[k]) - f64::from(mean[k])).powi(2))
            .sum::<f64>()
            / n;
        var.sqrt() as f32
    })
}

/// The mean of `frames` of `dim` coordinates each (zeros when there are none).
fn mean<'a>(frames: impl Iterator<Item = &'a Vec<f32>>, dim: usize) -> Vec<f32> {
    let mut sum = vec![0.0f64; dim];
    let mut n = 0usize;
    for f in frames {
        for (s, x) in sum.iter_mut().zip(f) {
            *s += f64::from(*x);
        }
        n += 1;
    }
    sum.iter().map(|s| (s / n.max(1) as f64) as f32).collect()
}

/// Every tracked video frame of `clips` as one point track.
pub fn contour_track(clips: &[&ContourClip]) -> Result<PointTrack, DecomposeError> {
    let mut track = PointTrack::new(2, CONTOUR_COORDS);
    for frame in clips.iter().flat_map(|c| c.contours.iter().flatten()) {
        track.push(frame)?;
    }
    Ok(track)
}

/// Lip gap (inner midpoints 13-14) and width (corners 61-291) of a contour, in eye widths.
pub fn gap_and_width(contour: &[f32]) -> (f32, f32) {
    let point = |landmark: usize| {
        let i = CONTOUR.iter().position(|&l| l == landmark).unwrap_or(0);
        (contour[2 * i], contour[2 * i + 1])
    };
    let (u, l) = (point(13), point(14));
    let (r, left) = (point(61), point(291));
    (l.1 - u.1, (left.0 - r.0).hypot(left.1 - r.1))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> String {
        let mut h = String::from("time_s,tracked");
        for l in [NOSE_TIP, RIGHT_EYE_OUTER, LEFT_EYE_OUTER]
            .into_iter()
            .chain(CONTOUR)
        {
            h.push_str(&format!(",x_{l},y_{l},z_{l}"));
        }
        h
    }

    /// A face with eyes 60 px apart, rotated by `angle` about the nose; every lip point at
    /// (dx, dy) px from the nose (before rotation) by its index.
    fn row(angle: f32, open: f32) -> String {
        let (s, c) = angle.sin_cos();
        let nose = [160.0f32, 160.0];
        let place = |x: f32, y: f32| [nose[0] + c * x - s * y, nose[1] + s * x + c * y];
        let mut r = String::from("0.02,1");
        let mut push = |p: [f32; 2]| r.push_str(&format!(",{},{},0", p[0], p[1]));
        push(nose);
        push(place(-30.0, -30.0));
        push(place(30.0, -30.0));
        for (k, l) in CONTOUR.iter().enumerate() {
            let y = if *l == 14 {
                45.0 + open
            } else {
                40.0 + k as f32 * 0.1
            };
            push(place(k as f32 - 10.0, y));
        }
        r
    }

    #[test]
    fn contours_take_head_motion_out_and_measure_the_gap_in_eye_widths() {
        let path = Path::new("t.csv");
        let text = format!(
            "{}\n{}\n{}\n0.1,0\n",
            header(),
            row(0.0, 1.0),
            row(0.4, 1.0)
        );
        let frames = parse_contours(&text, path).unwrap();
        assert_eq!(frames.len(), 3);
        assert!(frames[2].is_none());
        let (a, b) = (frames[0].as_ref().unwrap(), frames[1].as_ref().unwrap());
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() < 1e-4, "{a:?} vs {b:?}");
        }
        let (gap, _) = gap_and_width(a);
        // Inner midpoints 13 (k = 14, y 41.4) and 14 (y 46): 4.6 px over 60 px.
        assert!((gap - 4.6 / 60.0).abs() < 1e-4, "{gap}");
        assert!(parse_contours("", path).is_err());
        assert!(parse_contours("time_s,tracked\n", path).is_err());
        let bad = format!(
            "{}\n{}",
            header(),
            row(0.0, 1.0).replace("0.02,1,160", "0.02,1,zz")
        );
        assert!(parse_contours(&bad, path).is_err());
    }

    #[test]
    fn key_shapes_are_the_mean_contour_at_phone_centres() {
        let phones = [
            ("h#", 0, 3200),
            ("aa", 3200, 6400),
            ("ay", 6400, 12800),
            ("hh", 12800, 14400),
            ("iy", 14400, 16000),
        ];
        let segments: Vec<PhoneSegment> = phones
            .iter()
            .map(|&(p, s, e)| PhoneSegment {
                start: s,
                end: e,
                phone: p.into(),
            })
            .collect();
        let centres = phone_centres(&segments);
        let names: Vec<&str> = centres.iter().map(|(_, v)| v.name()).collect();
        assert_eq!(names, ["sil", "aa", "aa", "I", "I"]);
        assert!((centres[1].0 - 0.3).abs() < 1e-9 && (centres[3].0 - 0.7).abs() < 1e-9);
        // 25 video frames whose every coordinate is the frame's time in seconds.
        let contours: Vec<Option<Vec<f32>>> = (0..25)
            .map(|i| Some(vec![(i as f32 + 0.5) / 25.0; CONTOUR_COORDS]))
            .collect();
        let clip = ContourClip {
            name: "c".into(),
            contours,
            lips: Vec::new(),
            centres,
        };
        let (shapes, counts) = key_shapes(&[&clip], 0.0, 1, KeyRule::Mean).unwrap();
        assert_eq!(counts[Viseme::Aa.index()], 2);
        let aa = shapes.shape(Viseme::Aa).unwrap();
        assert!((aa[0] - 0.4).abs() < 1e-5, "{}", aa[0]);
        assert!(shapes.shape(Viseme::U).is_err());
        // All centres' mean is 0.51 (0.1, 0.3, 0.5, 0.7, 0.95), aa's own 0.4: the clearest of
        // aa's two lies furthest below, at 0.3.
        let (clearest, _) = key_shapes(&[&clip], 0.0, 1, KeyRule::ClearestQuarter).unwrap();
        let aa = clearest.shape(Viseme::Aa).unwrap();
        assert!((aa[0] - 0.3).abs() < 1e-5, "{}", aa[0]);
        let (shapes, _) = key_shapes(&[&clip], 0.0, 2, KeyRule::Mean).unwrap();
        assert_eq!(shapes.visemes(), [Viseme::Aa, Viseme::I]);
        assert_eq!(contour_track(&[&clip]).unwrap().len(), 25);
    }

    #[test]
    fn viseme_lips_are_measured_from_each_clips_own_rest() {
        let lips = |a: f32, w: f32| LipTargets {
            aperture: a,
            width: w,
            protrusion: 0.1,
            lower_lip_back: 0.0,
        };
        // Frame i's centre is (i + 0.5) / 25 s: frames 0 and 9 silent, 2-3 aa, 5-6 U, 7 untracked.
        let clip = |offset: f32| {
            let mut frames = vec![Some(lips(0.01, 0.6 + offset)); 10];
            for i in [2, 3] {
                frames[i] = Some(lips(0.15, 0.62 + offset));
            }
            for i in [5, 6] {
                frames[i] = Some(lips(0.03, 0.52 + offset));
            }
            frames[7] = None;
            ContourClip {
                name: "c".into(),
                contours: Vec::new(),
                lips: frames,
                centres: vec![
                    (0.02, Viseme::Sil),
                    (0.1, Viseme::Aa),
                    (0.14, Viseme::Aa),
                    (0.22, Viseme::U),
                    (0.3, Viseme::U), // untracked next frame: no measure
                    (0.38, Viseme::Sil),
                ],
            }
        };
        // A second recording sits 0.1 eye widths wider throughout: the rest takes it out.
        let (a, b) = (clip(0.0), clip(0.1));
        let (rest, rows) = viseme_lips(&[&a, &b], 0.0, 1);
        assert!((rest[1] - 0.65).abs() < 1e-5, "{rest:?}");
        let names: Vec<&str> = rows.iter().map(|r| r.viseme.name()).collect();
        assert_eq!(names, ["aa", "U"]);
        let (aa, u) = (&rows[0], &rows[1]);
        assert_eq!((aa.centres, u.centres), (4, 2));
        for (row, want) in [(aa, [0.14, 0.02, 0.0, 0.0]), (u, [0.02, -0.08, 0.0, 0.0])] {
            for (k, want) in want.iter().enumerate() {
                assert!((row.mean[k] - want).abs() < 1e-5, "{row:?}");
                assert!((row.clear[k] - want).abs() < 1e-5, "{row:?}");
                assert!(row.sd[k] < 1e-5, "{row:?}");
            }
        }
        let (_, few) = viseme_lips(&[&a, &b], 0.0, 3);
        assert_eq!(few.len(), 1);
    }

    proptest::proptest! {
        /// Any rows under a valid header are contours or an error, never a panic; so is
        /// interpolating whatever was parsed.
        #[test]
        fn contour_parsing_never_panics(rows in "[0-9,.x1\\-\n]{0,400}", t in -1.0f64..5.0) {
            if let Ok(frames) = parse_contours(&format!("{}\n{rows}", header()), Path::new("t.csv")) {
                let _ = contour_at(&frames, t);
            }
        }
    }
}
